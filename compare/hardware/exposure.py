"""Whether the ROS graph the bridge joins is reachable from the network (no ROS import, nothing sent).

ROS 1 has no authentication: whoever reaches the master can register a publisher on the
driver's command topic, and whoever reaches a node's ports can talk to it. The bridge therefore
starts only when everything it can check stays on loopback, unless the user opts in
(``--allow-network-master`` or ``hardware.allow_network_master``):

* ``ROS_MASTER_URI`` names a loopback host: a literal loopback address (``127.0.0.0/8``,
  ``::1``, ``::ffff:127.x``) or ``localhost``; any other name counts as remote, since telling
  what it resolves to could send a DNS query;
* the master's port has no listening socket of this machine bound beyond loopback (roscore
  binds ``0.0.0.0`` unless ``ROS_IP``/``ROS_HOSTNAME`` is a loopback address, whatever the URI
  says);
* this node would bind loopback only: rospy binds every server socket to
  :func:`node_bind_address`, decided by ``__ip:=``/``__hostname:=``, ``ROS_HOSTNAME``, ``ROS_IP``
  (in that order, as ``rosgraph.network.get_bind_address``); after the node has started,
  :func:`exposed_own_sockets` lists the sockets this process really listens on.

The sockets are read from ``/proc/net/tcp`` and ``/proc/net/tcp6`` (every listening TCP
socket of this network namespace) and ``/proc/self/fd`` (which of them belong to this process).
"""

from __future__ import annotations

import ipaddress
import os
import socket
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

from compare.hardware.exceptions import HardwareError, StartRefused

DEFAULT_MASTER_URI = "http://localhost:11311/"
"""What rospy uses when ``ROS_MASTER_URI`` is not set (``rosgraph.rosenv.DEFAULT_MASTER_URI``)."""
PROC_NET = Path("/proc/net")
TCP_LISTEN = "0A"
"""State column of a listening socket in ``/proc/net/tcp``."""
OPT_IN = "pass --allow-network-master or set hardware.allow_network_master = true to run anyway (docs/hardware.md)"


class NetworkExposed(StartRefused):
    """The master or this node is reachable beyond loopback and the user did not opt in."""


@dataclass(frozen=True)
class ListeningSocket:
    """One listening TCP socket of this machine.

    Attributes:
        address: Bound address (``0.0.0.0`` / ``::`` = every interface).
        port: TCP port.
        inode: Socket inode (matches ``socket:[inode]`` in ``/proc/<pid>/fd``).
    """

    address: str
    port: int
    inode: int

    @property
    def loopback(self) -> bool:
        """Whether only this machine can connect to it."""
        return is_loopback_host(self.address)

    def describe(self) -> str:
        """``address:port``, with ``(all interfaces)`` for a wildcard bind."""
        ip = ipaddress.ip_address(self.address)
        where = f"[{self.address}]:{self.port}" if ip.version == 6 else f"{self.address}:{self.port}"
        return where + (" (all interfaces)" if ip.is_unspecified else "")


def is_loopback_host(host: str) -> bool:
    """Whether ``host`` is a loopback address or ``localhost`` (no name is resolved).

    An IPv4-mapped IPv6 address counts by its IPv4 part.
    """
    host = host.strip().strip("[]").lower()
    if host in ("localhost", "localhost."):
        return True
    try:
        ip = ipaddress.ip_address(host)
    except ValueError:
        return False
    if isinstance(ip, ipaddress.IPv6Address) and ip.ipv4_mapped is not None:
        return ip.ipv4_mapped.is_loopback
    return ip.is_loopback


def _decode_address(hex_address: str) -> str:
    """An address of ``/proc/net/tcp{,6}`` (32-bit words in host byte order, hex) as text."""
    raw = bytes.fromhex(hex_address)
    if len(raw) not in (4, 16):
        raise ValueError(f"address {hex_address!r} is neither IPv4 nor IPv6")
    words = b"".join(raw[i : i + 4][::-1] for i in range(0, len(raw), 4)) if _little_endian() else raw
    return str(ipaddress.ip_address(words))


def _little_endian() -> bool:
    return socket.htonl(1) != 1


def parse_proc_net_tcp(text: str) -> list[ListeningSocket]:
    """The listening sockets of one ``/proc/net/tcp`` or ``/proc/net/tcp6`` table.

    Raises:
        HardwareError: a line that is not a socket entry.
    """
    out = []
    for line in text.splitlines()[1:]:
        cols = line.split()
        if not cols:
            continue
        try:
            local, state, inode = cols[1], cols[3], int(cols[9])
            hex_address, hex_port = local.split(":")
            if state != TCP_LISTEN:
                continue
            out.append(ListeningSocket(_decode_address(hex_address), int(hex_port, 16), inode))
        except (IndexError, ValueError) as exc:
            raise HardwareError(f"cannot read the listening sockets: bad line {line.strip()!r} ({exc})") from None
    return out


def listening_sockets(proc_net: Path = PROC_NET) -> list[ListeningSocket]:
    """Every listening TCP socket of this machine's network namespace (IPv4 and IPv6).

    Raises:
        HardwareError: ``/proc/net/tcp`` cannot be read (not Linux): nothing can be decided.
    """
    out: list[ListeningSocket] = []
    for name in ("tcp", "tcp6"):
        path = proc_net / name
        try:
            text = path.read_text(encoding="ascii")
        except FileNotFoundError:
            if name == "tcp6":  # IPv6 disabled
                continue
            raise HardwareError(f"cannot read {path}: the listening sockets are unknown") from None
        except OSError as exc:
            raise HardwareError(f"cannot read {path}: {exc}") from None
        out.extend(parse_proc_net_tcp(text))
    return out


def own_socket_inodes(fd_dir: Path = Path("/proc/self/fd")) -> set[int]:
    """Inodes of the sockets this process holds open."""
    inodes = set()
    for entry in fd_dir.iterdir():
        try:
            target = os.readlink(entry)
        except OSError:  # closed meanwhile
            continue
        if target.startswith("socket:[") and target.endswith("]"):
            inodes.add(int(target[len("socket:[") : -1]))
    return inodes


def exposed_own_sockets(sockets: Iterable[ListeningSocket] | None = None) -> list[ListeningSocket]:
    """The sockets this process listens on beyond loopback (empty: none)."""
    mine = own_socket_inodes()
    return [s for s in (listening_sockets() if sockets is None else sockets) if s.inode in mine and not s.loopback]


def master_uri(environ: Mapping[str, str], argv: Sequence[str]) -> str:
    """The master URI rospy would use: ``__master:=`` on the command line, ``ROS_MASTER_URI``, or the default."""
    for arg in argv:
        if arg.startswith("__master:="):
            return arg.split(":=", 1)[1]
    return environ.get("ROS_MASTER_URI", DEFAULT_MASTER_URI)


def split_master_uri(uri: str) -> tuple[str, int]:
    """Host and port of a master URI.

    Raises:
        HardwareError: not an ``http://host:port`` URI.
    """
    try:
        parts = urlsplit(uri)
        port = parts.port
    except ValueError as exc:
        raise HardwareError(f"ROS_MASTER_URI {uri!r} is not a URI: {exc}") from None
    if parts.scheme != "http" or not parts.hostname or port is None:
        raise HardwareError(f"ROS_MASTER_URI {uri!r} is not of the form http://host:port")
    return parts.hostname, port


def node_bind_address(environ: Mapping[str, str], argv: Sequence[str]) -> tuple[str, str]:
    """The address rospy binds this node's servers to, and what decided it.

    Mirrors ``rosgraph.network.get_bind_address``: the override (``__hostname:=``/``__ip:=``,
    else ``ROS_HOSTNAME`` even when empty, else ``ROS_IP``) binds loopback only when it is
    ``localhost``, starts with ``127.`` or is ``::1``; anything else binds every interface.

    Returns:
        (address, source): e.g. ``("127.0.0.1", "ROS_IP=127.0.0.1")`` or
        ``("0.0.0.0", "neither ROS_IP nor ROS_HOSTNAME is set")``.
    """
    override: str | None = None
    source = "neither ROS_IP nor ROS_HOSTNAME is set"
    for arg in argv:
        if arg.startswith(("__hostname:=", "__ip:=")):
            name, override = arg.split(":=", 1)
            source = f"{name}:={override}"
            break
    else:
        for var in ("ROS_HOSTNAME", "ROS_IP"):
            if var in environ:
                override, source = environ[var], f"{var}={environ[var]}"
                break
    ipv6 = environ.get("ROS_IPV6") == "on"
    if override and (override == "localhost" or override.startswith("127.") or override == "::1"):
        if ipv6:
            return "::1", source
        return (override if override.startswith("127.") else "127.0.0.1"), source
    return ("::" if ipv6 else "0.0.0.0"), source


@dataclass
class ExposureReport:
    """What the check found (``summary.json``: ``hardware.network``).

    Attributes:
        master_uri: The master URI checked.
        master_loopback: Whether its host is a loopback address.
        master_sockets: This machine's listening sockets on the master's port (``address:port``).
        node_bind_address: Where this node's servers will listen, and why.
        problems: Every exposure found, one sentence each (empty: loopback only).
        allowed: The user opted in: the problems are warnings, not a refusal.
        node_sockets: This process's listening sockets once the node runs (filled after start).
    """

    master_uri: str
    master_loopback: bool
    master_sockets: list[str]
    node_bind_address: str
    problems: list[str]
    allowed: bool
    node_sockets: list[str] = field(default_factory=list)

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready copy."""
        return {
            "master_uri": self.master_uri,
            "master_loopback": self.master_loopback,
            "master_sockets": list(self.master_sockets),
            "node_bind_address": self.node_bind_address,
            "node_sockets": list(self.node_sockets),
            "problems": list(self.problems),
            "allowed": self.allowed,
        }


def check_exposure(
    environ: Mapping[str, str],
    argv: Sequence[str],
    allowed: bool,
    sockets: Sequence[ListeningSocket] | None = None,
) -> ExposureReport:
    """Decide, before any connection, whether the master or this node would be reachable from the network.

    Args:
        environ: The environment rospy will read.
        argv: The command line rospy will read (remappings ``__master:=``, ``__ip:=``, ...).
        allowed: The user opted in (problems are reported, not refused).
        sockets: This machine's listening sockets (default: :func:`listening_sockets`).

    Raises:
        NetworkExposed: a problem found and ``allowed`` is false (one line naming the
            variable or the socket).
        HardwareError: a malformed ``ROS_MASTER_URI``, or the sockets cannot be read.
    """
    uri = master_uri(environ, argv)
    host, port = split_master_uri(uri)
    loopback = is_loopback_host(host)
    problems = []
    if not loopback:
        problems.append(f"ROS_MASTER_URI={uri} names {host}, not a loopback address (127.0.0.1, ::1, localhost)")
    listening = listening_sockets() if sockets is None else sockets
    on_port = [s for s in listening if s.port == port] if loopback else []
    for s in on_port:
        if not s.loopback:
            problems.append(
                f"the ROS master (port {port}) listens on {s.describe()}: start roscore with ROS_IP=127.0.0.1"
            )
    bind, source = node_bind_address(environ, argv)
    if not is_loopback_host(bind):
        problems.append(f"this node would listen on {bind} (all interfaces) because {source}: {_bind_hint(source)}")
    report = ExposureReport(uri, loopback, [s.describe() for s in on_port], f"{bind} ({source})", problems, allowed)
    if problems and not allowed:
        raise NetworkExposed("; ".join(problems) + f"; {OPT_IN}")
    return report


def _bind_hint(source: str) -> str:
    """How to make this node bind loopback, given what decided its address."""
    if source.startswith("ROS_HOSTNAME"):
        return "set ROS_HOSTNAME=localhost (or unset it and set ROS_IP=127.0.0.1)"
    if source.startswith("__"):
        return f"drop the remapping {source} or make it 127.0.0.1"
    return "set ROS_IP=127.0.0.1"

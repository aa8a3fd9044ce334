"""A real roscore on loopback, and helpers to run the stand-in and ``tpik-compare hw`` against it.

Every process is started in its own session and killed (its whole process group, by id) in
teardown; every wait is bounded.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
import tomllib
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
import tomli_w

from compare.hardware.ros_env import ros_unavailable_reason

ROOT = Path(__file__).resolve().parents[2]
CONFIGS = ROOT / "configs"


def ros_skip_reason() -> str | None:
    """Why the ROS tests cannot run here, or None."""
    reason = ros_unavailable_reason()
    if reason is not None:
        return reason
    if shutil.which("roscore") is None:
        return "roscore not found (run `make hw-deps`)"
    return None


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def kill_group(proc: subprocess.Popen[Any], grace_s: float = 5.0, first: int = signal.SIGINT) -> None:
    """Stop a process started with ``start_new_session=True`` and its children (its own group)."""
    if proc.poll() is not None:
        return
    try:
        os.killpg(proc.pid, first)
        proc.wait(timeout=grace_s)
    except (ProcessLookupError, subprocess.TimeoutExpired):
        pass
    if proc.poll() is None:
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        proc.wait(timeout=5.0)


@pytest.fixture(scope="module")
def ros_env(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, str]]:
    """Environment of a fresh roscore on 127.0.0.1:<random free port>."""
    from compare.hardware.ros_io import master_online

    reason = ros_skip_reason()
    if reason is not None:
        pytest.skip(f"ROS 1 not available: {reason}")
    home = tmp_path_factory.mktemp("roshome")
    port = free_port()
    env = dict(os.environ)
    env.pop("ROS_HOSTNAME", None)
    env.update(
        ROS_MASTER_URI=f"http://127.0.0.1:{port}",
        ROS_IP="127.0.0.1",
        ROS_HOME=str(home),
        ROS_LOG_DIR=str(home / "log"),
        MUJOCO_GL=os.environ.get("MUJOCO_GL", "egl"),
        PYTHONUNBUFFERED="1",
    )
    log = open(home / "roscore.log", "w")  # noqa: SIM115 - closed in teardown
    proc = subprocess.Popen(
        ["roscore", "-p", str(port)], env=env, stdout=log, stderr=subprocess.STDOUT, start_new_session=True
    )
    try:
        deadline = time.monotonic() + 20.0
        while not master_online(env["ROS_MASTER_URI"], 0.5):
            if proc.poll() is not None or time.monotonic() > deadline:
                pytest.fail(f"roscore did not come up: {(home / 'roscore.log').read_text()[-2000:]}")
            time.sleep(0.1)
        yield env
    finally:
        kill_group(proc)
        log.close()


@dataclass
class Proc:
    """A started process and where its output goes."""

    popen: subprocess.Popen[Any]
    log_path: Path

    def output(self) -> str:
        return self.log_path.read_text(errors="replace") if self.log_path.exists() else ""


@pytest.fixture
def procs() -> Iterator[list[Proc]]:
    """Processes a test starts; all killed in teardown."""
    started: list[Proc] = []
    yield started
    for p in started:
        kill_group(p.popen, first=signal.SIGTERM)


def start(procs: list[Proc], env: dict[str, str], args: list[str], log_path: Path) -> Proc:
    fh = open(log_path, "w")  # noqa: SIM115 - the child owns it
    popen = subprocess.Popen(
        [sys.executable, *args], env=env, stdout=fh, stderr=subprocess.STDOUT, cwd=ROOT, start_new_session=True
    )
    fh.close()
    proc = Proc(popen, log_path)
    procs.append(proc)
    return proc


def write_config(path: Path, base: str | Path = "case1.toml", **sections: dict[str, Any]) -> Path:
    """``configs/<base>`` (or the file ``base``) with sections updated key by key, written to ``path``."""
    with open(CONFIGS / base, "rb") as fh:
        data = tomllib.load(fh)
    for name, values in sections.items():
        data.setdefault(name, {}).update(values)
    path.write_bytes(tomli_w.dumps(data).encode())
    return path


def read_json(path: Path) -> dict[str, Any]:
    return json.loads(path.read_text())


@dataclass
class SocketCalls:
    """Every connection, datagram and name lookup a test's code attempted (none is carried out)."""

    calls: list[tuple[str, Any]]


@pytest.fixture
def no_socket_calls(monkeypatch: pytest.MonkeyPatch) -> SocketCalls:
    """Record and refuse every outgoing connection, datagram and name lookup of this process.

    A refused attempt raises ``OSError`` before anything is sent, so code under test that would
    reach for the network (or for a DNS server) sends nothing, and the test sees that it tried.
    """
    record = SocketCalls([])

    def refuse(what: str) -> Any:
        def call(*args: Any, **kwargs: Any) -> Any:
            record.calls.append((what, args[1:] if args and isinstance(args[0], socket.socket) else args))
            raise OSError(f"{what} refused by the test")

        return call

    for name in ("connect", "connect_ex", "sendto", "sendmsg"):
        monkeypatch.setattr(socket.socket, name, refuse(name))
    monkeypatch.setattr(socket, "create_connection", refuse("create_connection"))
    monkeypatch.setattr(socket, "getaddrinfo", refuse("getaddrinfo"))
    monkeypatch.setattr(socket, "gethostbyname", refuse("gethostbyname"))
    return record

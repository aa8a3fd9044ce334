"""The bridge refuses a ROS master or node reachable beyond loopback, before any connection.

The tables of ``/proc/net/tcp{,6}`` are hand-built where a wildcard socket is needed; the only
real wildcard socket is the master of ``test_a_master_listening_on_all_interfaces_is_refused``
(``rosmaster`` without ``ROS_IP``, what roscore starts), which nothing connects to but the test's
loopback probe. Every test sends to loopback only; the refusals run with every outgoing
connection and name lookup refused and recorded (``no_socket_calls``).
"""

from __future__ import annotations

import os
import shutil
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from compare.hardware.exceptions import HardwareError
from compare.hardware.exposure import (
    ListeningSocket,
    NetworkExposed,
    check_exposure,
    exposed_own_sockets,
    is_loopback_host,
    listening_sockets,
    node_bind_address,
    own_socket_inodes,
    parse_proc_net_tcp,
)
from tests.hardware.conftest import ROOT, free_port, kill_group, ros_skip_reason, write_config

HEADER = "  sl  local_address rem_address   st tx_queue rx_queue tr tm->when retrnsmt   uid  timeout inode\n"
LOOPBACK_NODE = {"ROS_MASTER_URI": "http://127.0.0.1:11311", "ROS_IP": "127.0.0.1"}


def _row(local: str, state: str, inode: int) -> str:
    rest = f"00000000:00000000 00:00000000 00000000  1000  0 {inode} 1 0 100 0 0 10 0"
    return f"   0: {local} 00000000:0000 {state} {rest}\n"


@pytest.mark.skipif(sys.byteorder != "little", reason="the hand-built rows are those of a little-endian kernel")
def test_proc_net_rows_give_the_listening_addresses_and_ports():
    v4 = HEADER + _row("0100007F:2C2F", "0A", 11) + _row("00000000:2C2F", "0A", 12) + _row("0100007F:9C40", "01", 13)
    v6 = HEADER + _row("00000000000000000000000001000000:0050", "0A", 21)
    v6 += _row("00000000000000000000000000000000:0051", "0A", 22)
    v6 += _row("0000000000000000FFFF00000100007F:0052", "0A", 23)
    got = parse_proc_net_tcp(v4) + parse_proc_net_tcp(v6)
    assert [(s.address, s.port, s.inode) for s in got] == [
        ("127.0.0.1", 11311, 11), ("0.0.0.0", 11311, 12),  # the established connection (01) is left out
        ("::1", 80, 21), ("::", 81, 22), ("::ffff:7f00:1", 82, 23),  # ::ffff:127.0.0.1
    ]  # fmt: skip
    assert [s.loopback for s in got] == [True, False, True, False, True]
    assert got[1].describe() == "0.0.0.0:11311 (all interfaces)" and got[3].describe() == "[::]:81 (all interfaces)"


def test_a_garbled_proc_net_row_is_one_clear_error():
    with pytest.raises(HardwareError, match="cannot read the listening sockets"):
        parse_proc_net_tcp(HEADER + "   0: 0100007F 00000000:0000 0A\n")


def test_a_real_loopback_listener_is_found_as_this_process_own_and_not_exposed():
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        mine = [x for x in listening_sockets() if x.port == port]
        assert len(mine) == 1 and mine[0].address == "127.0.0.1" and mine[0].loopback
        assert mine[0].inode in own_socket_inodes()
        assert exposed_own_sockets() == []
        # The same socket as a wildcard bind would be: reported as this process's exposure.
        wildcard = ListeningSocket("0.0.0.0", port, mine[0].inode)
        assert exposed_own_sockets([wildcard, ListeningSocket("0.0.0.0", 1, 1)]) == [wildcard]


@pytest.mark.parametrize(
    ("host", "loopback"),
    [("127.0.0.1", True), ("127.4.5.6", True), ("::1", True), ("[::1]", True), ("localhost", True),
     ("::ffff:127.0.0.1", True), ("192.0.2.1", False), ("0.0.0.0", False), ("::", False), ("robot-pc", False),
     ("127.0.0.1.example.org", False), ("10.0.0.2", False), ("::ffff:192.0.2.1", False)],
)  # fmt: skip
def test_only_loopback_addresses_and_localhost_count_as_loopback(host, loopback):
    assert is_loopback_host(host) is loopback


NODE_ENVS = [
    ({}, []),
    ({"ROS_IP": "127.0.0.1"}, []),
    ({"ROS_IP": "127.0.0.2"}, []),
    ({"ROS_IP": "192.0.2.5"}, []),
    ({"ROS_HOSTNAME": "localhost"}, []),
    ({"ROS_HOSTNAME": "vm", "ROS_IP": "127.0.0.1"}, []),  # ROS_HOSTNAME wins, even over a loopback ROS_IP
    ({"ROS_HOSTNAME": "", "ROS_IP": "127.0.0.1"}, []),  # an empty ROS_HOSTNAME still wins
    ({"ROS_IP": "::1", "ROS_IPV6": "on"}, []),
    ({"ROS_IPV6": "on"}, []),
    ({"ROS_IP": "192.0.2.5"}, ["__ip:=127.0.0.1"]),  # a remapping wins over the environment
    ({"ROS_IP": "127.0.0.1"}, ["__hostname:=robot-pc"]),
]


@pytest.mark.parametrize(("env", "argv"), NODE_ENVS)
def test_the_node_bind_address_is_the_one_rosgraph_computes(monkeypatch, env, argv):
    if ros_skip_reason() is not None:
        pytest.skip(f"ROS 1 not available: {ros_skip_reason()}")
    from compare.hardware.ros_env import load_ros

    load_ros()  # makes Debian's rosgraph importable
    import rosgraph.network

    for var in ("ROS_IP", "ROS_HOSTNAME", "ROS_IPV6"):
        monkeypatch.delenv(var, raising=False)
    for var, value in env.items():
        monkeypatch.setenv(var, value)
    monkeypatch.setattr(sys, "argv", ["tpik-compare", *argv])
    ours, source = node_bind_address(dict(os.environ), sys.argv)
    assert ours == rosgraph.network.get_bind_address(), (env, argv, source)


def _sockets(*described: tuple[str, int]) -> list[ListeningSocket]:
    return [ListeningSocket(a, p, 1000 + i) for i, (a, p) in enumerate(described)]


def test_each_exposure_is_refused_in_one_line_naming_the_variable_or_the_socket():
    with pytest.raises(NetworkExposed) as remote:
        check_exposure({**LOOPBACK_NODE, "ROS_MASTER_URI": "http://robot-pc:11311"}, [], False, [])
    assert "ROS_MASTER_URI=http://robot-pc:11311 names robot-pc" in str(remote.value)
    with pytest.raises(NetworkExposed) as wildcard:
        check_exposure(LOOPBACK_NODE, [], False, _sockets(("127.0.0.1", 11311), ("0.0.0.0", 11311)))
    assert "listens on 0.0.0.0:11311 (all interfaces)" in str(wildcard.value)
    with pytest.raises(NetworkExposed) as v6:
        check_exposure(LOOPBACK_NODE, [], False, _sockets(("::", 11311)))
    assert "[::]:11311 (all interfaces)" in str(v6.value)
    with pytest.raises(NetworkExposed) as node:
        check_exposure({"ROS_MASTER_URI": "http://127.0.0.1:11311"}, [], False, _sockets(("127.0.0.1", 11311)))
    assert "neither ROS_IP nor ROS_HOSTNAME is set: set ROS_IP=127.0.0.1" in str(node.value)
    with pytest.raises(NetworkExposed) as hostname:
        check_exposure({**LOOPBACK_NODE, "ROS_HOSTNAME": "vm"}, [], False, [])
    assert "ROS_HOSTNAME=vm" in str(hostname.value) and "ROS_HOSTNAME=localhost" in str(hostname.value)
    for exc in (remote, wildcard, v6, node, hostname):
        assert "\n" not in str(exc.value) and "--allow-network-master" in str(exc.value)


def test_a_loopback_master_and_node_pass_and_an_opt_in_reports_instead_of_refusing():
    ok = check_exposure(LOOPBACK_NODE, [], False, _sockets(("127.0.0.1", 11311), ("0.0.0.0", 2024)))
    assert ok.problems == [] and ok.master_sockets == ["127.0.0.1:11311"] and ok.master_loopback
    assert ok.node_bind_address.startswith("127.0.0.1")
    unset = check_exposure({"ROS_IP": "127.0.0.1"}, [], False, [])  # rospy's default URI: localhost:11311
    assert unset.master_uri == "http://localhost:11311/" and unset.problems == []
    allowed = check_exposure({"ROS_MASTER_URI": "http://192.0.2.1:11311"}, [], True, [])
    assert len(allowed.problems) == 2 and allowed.as_dict()["allowed"] is True


@pytest.mark.parametrize("uri", ["127.0.0.1:11311", "http://127.0.0.1", "https://127.0.0.1:11311", "http://[::1:11311"])
def test_a_malformed_master_uri_is_one_clear_error(uri):
    with pytest.raises(HardwareError, match="ROS_MASTER_URI"):
        check_exposure({**LOOPBACK_NODE, "ROS_MASTER_URI": uri}, [], False, [])


def _cli(argv: list[str]) -> int:
    from compare.cli import main

    with pytest.raises(SystemExit) as done:
        main(argv)
    return int(done.value.code or 0)


@pytest.fixture
def hw_config(tmp_path: Path) -> Path:
    """configs/case1.toml with a camera pose (the pose only has to exist: nothing gets to the camera)."""
    return write_config(
        tmp_path / "hw.toml",
        methods={"names": ["tpik"]},
        hardware={"camera_translation_m": [0.0, -1.9, 1.55], "camera_quaternion_xyzw": [-0.8660254, 0.0, 0.0, 0.5],
                  "startup_timeout_s": 1.0},
    )  # fmt: skip


def _refused(argv: list[str], capsys: pytest.CaptureFixture[str], calls, what: str) -> None:
    assert _cli(argv) == 2
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.startswith("error:")]
    assert len(lines) == 1 and what in lines[0] and "Traceback" not in err, err
    assert calls.calls == []  # refused before any connection, lookup or datagram


def test_a_remote_master_uri_is_refused_before_connecting(monkeypatch, capsys, hw_config, tmp_path, no_socket_calls):
    monkeypatch.setenv("ROS_MASTER_URI", "http://192.0.2.1:11311")  # TEST-NET-1: nothing answers there anyway
    monkeypatch.setenv("ROS_IP", "127.0.0.1")
    monkeypatch.delenv("ROS_HOSTNAME", raising=False)
    what = "ROS_MASTER_URI=http://192.0.2.1:11311 names 192.0.2.1"
    _refused(["hw", str(hw_config), "--out", str(tmp_path / "hw"), "-q"], capsys, no_socket_calls, what)
    assert not (tmp_path / "hw").exists()  # refused before the results directory was made
    _refused(["hw-check", str(hw_config)], capsys, no_socket_calls, what)
    monkeypatch.setenv("ROS_MASTER_URI", "http://robot-pc.local:11311")  # a name: not resolved
    _refused(["hw-check", str(hw_config)], capsys, no_socket_calls, "names robot-pc.local")


@pytest.fixture
def wildcard_master(tmp_path: Path) -> tuple[dict[str, str], int]:
    """``rosmaster --core`` (the master roscore starts) without ROS_IP: it binds every interface."""
    from compare.hardware.master_api import master_online

    if ros_skip_reason() is not None or shutil.which("rosmaster") is None:
        pytest.skip(f"ROS 1 not available: {ros_skip_reason() or 'rosmaster not found'}")
    port = free_port()
    env = {k: v for k, v in os.environ.items() if k not in ("ROS_IP", "ROS_HOSTNAME", "ROS_IPV6")}
    env.update(ROS_MASTER_URI=f"http://127.0.0.1:{port}", ROS_HOME=str(tmp_path / "roshome"), PYTHONUNBUFFERED="1")
    log = tmp_path / "rosmaster.log"
    with open(log, "w") as fh:
        proc = subprocess.Popen(
            ["rosmaster", "--core", "-p", str(port)], env=env, stdout=fh, stderr=subprocess.STDOUT,
            start_new_session=True,
        )  # fmt: skip
    try:
        deadline = time.monotonic() + 20.0
        while not master_online(env["ROS_MASTER_URI"], 0.5):  # the probe goes to 127.0.0.1
            if proc.poll() is not None or time.monotonic() > deadline:
                pytest.fail(f"rosmaster did not come up: {log.read_text()[-2000:]}")
            time.sleep(0.1)
        yield env, port
    finally:
        kill_group(proc)


def test_a_master_listening_on_all_interfaces_is_refused_before_connecting(
    monkeypatch, capsys, hw_config, tmp_path, wildcard_master, no_socket_calls
):
    env, port = wildcard_master
    assert any(s.port == port and s.address in ("0.0.0.0", "::") for s in listening_sockets())
    monkeypatch.setenv("ROS_MASTER_URI", env["ROS_MASTER_URI"])
    monkeypatch.setenv("ROS_IP", "127.0.0.1")  # this node would be fine: the master is the problem
    monkeypatch.delenv("ROS_HOSTNAME", raising=False)
    what = f"the ROS master (port {port}) listens on"
    _refused(["hw", str(hw_config), "--out", str(tmp_path / "hw"), "-q"], capsys, no_socket_calls, what)
    _refused(["hw-check", str(hw_config)], capsys, no_socket_calls, what)
    # With the opt-in the start goes on: past the network and the master checks, to the data it waits for.
    opt_in = subprocess.run(
        [sys.executable, "-m", "compare.cli", "hw-check", str(hw_config), "--allow-network-master"],
        env={**env, "ROS_IP": "127.0.0.1"}, cwd=ROOT, capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert opt_in.returncode == 2, opt_in.stderr[-2000:]
    assert "network exposure allowed" in opt_in.stderr and "no joint state on" in opt_in.stderr


def test_a_loopback_only_master_is_accepted(ros_env, hw_config):
    """roscore with ROS_IP=127.0.0.1 binds loopback only: the check passes and the start goes on."""
    port = int(ros_env["ROS_MASTER_URI"].rsplit(":", 1)[1])
    report = check_exposure(ros_env, [], False)
    assert report.problems == [] and report.master_sockets == [f"127.0.0.1:{port}"]
    res = subprocess.run(
        [sys.executable, "-m", "compare.cli", "hw-check", str(hw_config)],
        env=ros_env, cwd=ROOT, capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert res.returncode == 2 and "no joint state on" in res.stderr, res.stderr[-2000:]  # nobody publishes
    assert "network exposure" not in res.stderr

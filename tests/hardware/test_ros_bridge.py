"""The hardware path end to end: roscore on loopback, the driver stand-in (driver timing model), ``tpik-compare hw``.

Times of published and received messages are on the machine's monotonic clock, shared by the
processes, so the stand-in's record and the bridge's report (``clock_start_monotonic_s``) can be
compared directly.

The machine running these tests may be shared and loaded: no assertion bounds how fast a
process gets the CPU. Reactions are checked by their order and cause (zero after the stall and
never a non-zero command after it; the watchdog never fires before its timeout; ``in/stop``
called after the halt), rates by agreement between what one side sent and the other received,
with only loose sanity bounds on the absolute times (measured values are printed).
"""

from __future__ import annotations

import re
import signal
import subprocess
import sys
import time
import tomllib
from itertools import pairwise
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from tests.hardware.conftest import CONFIGS, ROOT, Proc, read_json, ros_skip_reason, start, write_config

pytestmark = [
    pytest.mark.skipif(ros_skip_reason() is not None, reason=f"ROS 1 not available: {ros_skip_reason()}"),
    pytest.mark.realtime,
]

RUN_S = 9.0  # loop time of the case-1 run (the person steps in at 5 s, arrives at 7 s)
TIME_SCALE = 1.0
STEP_IN_SHIFT_S = 30.0
"""The person's keyframes come this much earlier than in configs/case1.toml (35 s → 5 s), so the
approach runs at the paper's speed (0.4 m in 2 s) in a short run. A compressed scenario
(time_scale 0.1) would make the person approach at ~3 m/s, where the few tens of milliseconds a
depth frame takes through ROS decide the margin and the comparison with simulation measures
this machine's load, not the bridge."""
EXECUTED_FULLY = 0.8  # executed motion ratio above which the arm did what an Ethernet arm does
OBSTACLE_SAFETY_M = 0.35  # configs/case1.toml's obstacle safety distance
HOLD_AT = [0.0, 0.4, 0.7]
"""One waypoint, between case 1's two, that the arm reaches and holds before the person comes:
what the person meets does not depend on how far along the waypoint cycle the arm has got
(which on a loaded machine depends on how fast the stand-in's clock runs)."""
TIMEOUT_S = 120.0
SANITY_S = 0.5  # loose upper bound on a reaction, beyond its timeout, on a loaded machine


@pytest.fixture(scope="module")
def case1_config(ros_env: dict[str, str], tmp_path_factory: pytest.TempPathFactory) -> Path:
    """configs/case1.toml, short form, tpik only; camera pose and background = the work cell's (perfect calibration)."""
    from compare.hardware.standin import camera_calibration

    d = tmp_path_factory.mktemp("cfg")
    background = d / "background.npz"
    subprocess.run(
        [sys.executable, "-m", "compare.hardware.standin", str(CONFIGS / "case1.toml"), "--write-background",
         str(background)], env=ros_env, cwd=ROOT, check=True, timeout=TIMEOUT_S, capture_output=True,
    )  # fmt: skip
    return write_config(
        d / "case1_hw.toml",
        scenario={"time_scale": TIME_SCALE},
        person={"keyframes": _keyframes_earlier(STEP_IN_SHIFT_S)},
        waypoints={"positions": [HOLD_AT], "cycle": False},
        methods={"names": ["tpik"]},
        # One stray pixel of the stand-in's render, 6 cm off the arm, once read as an obstacle
        # 4 cm from link_6 and made the arm escape (docs/hardware.md, "A phantom obstacle from one
        # pixel"); a real camera's flying pixels do the same. The second-nearest pixel per cube,
        # as a real setup would configure it; the simulation reference reads the same config.
        sensor={"min_support": 2},
        hardware={
            "startup_timeout_s": 60.0,
            "background_file": str(background),
            # The test machine is shared: its scheduling gaps (150 ms seen at a load of 9 on 2
            # cores) would trip the real defaults (111 ms USB / 50 ms Ethernet) and refuse the
            # start. The defaults themselves are checked against the driver model's own jitter
            # (below and in test_driver_model.py) and by the start-check tests.
            "state_timeout_periods": 20.0,
            "loop_timeout_s": 0.3,
            **camera_calibration(),
        },
    )


def _keyframes_earlier(shift_s: float) -> list[dict[str, Any]]:
    """configs/case1.toml's person keyframes, every one after t = 0 moved ``shift_s`` earlier."""
    keyframes = tomllib.loads((CONFIGS / "case1.toml").read_text())["person"]["keyframes"]
    return [{**k, "t": k["t"] - shift_s if k["t"] > 0.0 else 0.0} for k in keyframes]


def _with_hardware(config: Path, name: str, **values: Any) -> Path:
    """A copy of ``config`` with ``[hardware]`` keys set to ``values`` (existing keys replaced)."""
    return write_config(config.with_name(name), config, hardware=values)


def _toml(value: Any) -> str:
    if isinstance(value, str):
        return f'"{value}"'
    if isinstance(value, list | tuple):
        return "[" + ", ".join(repr(float(v)) for v in value) + "]"
    return repr(value)


def _standin(procs: list[Proc], env: dict[str, str], config: Path, tmp: Path, *extra: str) -> tuple[Proc, Path]:
    record = tmp / "standin_record.json"
    args = ["-m", "compare.hardware.standin", str(config), "--record", str(record), "--duration", "60", *extra]
    return start(procs, env, args, tmp / "standin.log"), record


def _hw(
    env: dict[str, str], config: Path, out: Path, *extra: str, timeout: float = TIMEOUT_S, command: str = "hw"
) -> subprocess.CompletedProcess[str]:
    args = [sys.executable, "-m", "compare.cli", command, str(config), *extra]
    if command == "hw":
        args += ["--out", str(out), "-q"]
    return subprocess.run(args, env=env, cwd=ROOT, capture_output=True, text=True, timeout=timeout)


def _stop(proc: Proc, record: Path) -> dict[str, Any]:
    proc.popen.send_signal(signal.SIGTERM)
    proc.popen.wait(timeout=30)
    assert record.exists(), proc.output()[-3000:]
    return read_json(record)


def _measured_safety(steps: Any, summary: dict[str, Any]) -> dict[str, Any]:
    """The simulation's metrics recomputed from measured distances only, as on the hardware path."""
    from compare.analysis.metrics import RunMeta, compute_summary, set_tasks_from_summary

    steps = steps.drop(columns=[c for c in steps.columns if c.startswith(("truth:", "dist_true:"))])
    meta = RunMeta("case1", 0, "tpik", summary["dt"], summary["sim_time_s"], summary["wall_time_s"], "depth",
                   set_tasks_from_summary(summary))  # fmt: skip
    return compute_summary(steps, meta)


def _fmt(g: dict[str, Any]) -> str:
    return (
        f"safety margin {g['safety_margin_min']:+.4f}, physical {g['physical_margin_min']:+.4f}, "
        f"{g['violations']} violations, {g['violation_time_s']:.2f} s"
    )


def _rate(times: list[float], t0: float, t1: float) -> float:
    t = np.array([x for x in times if t0 <= x <= t1])
    return (t.size - 1) / (t[-1] - t[0])


def _first_zero_after(rec: dict[str, Any], t: float) -> tuple[float, bool]:
    """Start of the all-zero stretch that ends the command stream after ``t``, and whether it exists.

    The controller may itself command zero now and then (at a waypoint, a fallback step), so the
    reaction to a halt is the start of the *final* run of zeros: after it no non-zero command
    ever reached the driver.
    """
    times = np.array(rec["command_t"])
    cmds = np.array(rec["command_deg_s"])
    after = np.flatnonzero(times > t)
    assert after.size, "no command after the stall"
    moving = np.flatnonzero(np.any(cmds[after], axis=1))
    first = int(after[moving[-1] + 1]) if moving.size else int(after[0])
    if moving.size and moving[-1] + 1 >= after.size:
        return float("inf"), False  # the stream ended moving
    return float(times[first]), True


def _error_line(stderr: str) -> str:
    """The one ``error:`` line of a refused start (log lines around it are INFO/WARNING)."""
    lines = [line for line in stderr.splitlines() if line.startswith("error:")]
    assert len(lines) == 1, stderr[-3000:]
    return lines[0]


def _services(rec: dict[str, Any]) -> list[tuple[str, float]]:
    return [(s["name"], s["requested_t"]) for s in rec["services"]]


def _stops_after(rec: dict[str, Any], t: float) -> list[float]:
    return [r for name, r in _services(rec) if name == "stop" and r > t]


def _sim_reference(env: dict[str, str], config: Path, out: Path) -> dict[str, Any]:
    res = subprocess.run(
        [sys.executable, "-m", "compare.cli", "run", str(config), "--out", str(out), "-q", "--no-plots",
         "--duration", str(RUN_S / TIME_SCALE)],
        env=env, cwd=ROOT, capture_output=True, text=True, timeout=TIMEOUT_S,
    )  # fmt: skip
    assert res.returncode == 0, res.stderr[-3000:]
    from compare.analysis.results import load_steps

    sim = read_json(out / "summary.json")["methods"]["tpik"]
    return {"sim": sim, "measured": _measured_safety(load_steps(out, "tpik"), sim)}


@pytest.fixture(scope="module")
def sim_reference(ros_env, case1_config, tmp_path_factory):
    """The pure simulation of the same short case 1 (once for both connections)."""
    return _sim_reference(ros_env, case1_config, tmp_path_factory.mktemp("sim") / "sim")


@pytest.mark.parametrize("connection", ["usb", "ethernet"])
def test_case1_through_the_driver_model_is_as_safe_as_in_simulation(
    ros_env, procs, case1_config, sim_reference, tmp_path, connection
):
    config = _with_hardware(case1_config, f"case1_{connection}.toml", connection_type=connection)
    bag = tmp_path / "streams.bag"
    standin, record = _standin(procs, ros_env, config, tmp_path, "--record-bag", str(bag))
    out = tmp_path / "hw"
    res = _hw(ros_env, config, out, "--duration", str(RUN_S))
    rec = _stop(standin, record)
    assert res.returncode == 0, res.stdout[-2000:] + res.stderr[-4000:]
    summary = read_json(out / "summary.json")
    hw = summary["methods"]["tpik"]
    report = hw["hardware"]
    assert (out / "steps").is_dir() and list((out / "plots").glob("*.png"))
    assert report["halt_cause"] is None and report["ignored_messages"] == {}  # the stand-in's messages are valid
    t0 = report["clock_start_monotonic_s"]
    t1 = t0 + hw["sim_time_s"]

    # What the driver model delivers in this mode (its own timing, not this machine's load).
    model_t = np.array([t for t in rec["state_model_t"] if t0 <= t <= t1])
    model_rate = (model_t.size - 1) / (model_t[-1] - model_t[0])
    window = [c for c in rec["commands"] if t0 + 0.5 <= c["arrival_t"] <= t1 - 0.5]
    dropped = sum(c["outcome"] == "dropped" for c in window) / len(window)
    # What the bridge saw: the same streams, measured on its side.
    rates = report["rates"]
    sent = rates["command"]["rate_hz"]
    received = _rate(rec["command_t"], t0 + 0.5, t1 - 0.5)
    print(f"\n{connection}: driver states {model_rate:.1f} Hz (bridge received {rates['joint_state']['rate_hz']:.1f}), "
          f"commands sent {sent:.1f} Hz / received {received:.1f} Hz, dropped by the driver's queue "
          f"{100 * dropped:.0f} %, executed motion ratio {report['executed_motion_ratio']:.2f}, "
          f"depth {rates['depth']['rate_hz']:.1f} Hz, start check {report['start_check']}")  # fmt: skip
    # (The fraction dropped depends on how the messages arrive: a starved process reads them in
    # bursts. Its mode dependence is tested in virtual time, test_driver_model.py.)
    if connection == "usb":
        assert 35.0 <= model_rate <= 60.0
    else:
        assert model_rate >= 85.0
    # The bridge's subscriber keeps only the newest state (queue 1): it may see fewer, never more.
    assert 0.5 * _rate(rec["joint_state_t"], t0, t1) <= rates["joint_state"]["rate_hz"]
    assert rates["joint_state"]["rate_hz"] <= 1.05 * _rate(rec["joint_state_t"], t0, t1)
    assert received == pytest.approx(sent, rel=0.1)  # loopback loses nothing
    # The stand-in stamps on this machine's clock: the bridge places states and frames by their
    # stamps (the self-filter) and reports how late they came (stamp → callback, within the window).
    for topic in ("joint_state", "depth"):
        lag = rates[topic]
        print(f"{topic} delivery lag p99 {lag['delivery_lag_p99_ms']:.1f} ms, max {lag['delivery_lag_max_ms']:.1f} ms")
        assert 0.0 <= lag["delivery_lag_p99_ms"] <= lag["delivery_lag_max_ms"] <= 500.0
    assert report["start_check"]["connection_type"] == connection

    # Same safety results as the pure simulation of the same scenario (acceptance: 0.02 m / 0.02 rad).
    # Over USB the arm executes about half of the commanded motion and lags the simulation: there
    # the obstacle results may only be *safer* than simulated, never less safe by more than
    # 0.02 m; over Ethernet (executed motion ratio ≥ EXECUTED_FULLY) they agree both ways. The
    # ground truth decides (below); the measured obstacle margin is the depth pipeline's reading
    # of it, sampled at other frames on each side, so it is allowed the simulation's own
    # measurement error on top.
    # A stand-in starved of CPU (this machine's load) also executes less than an Ethernet arm
    # would: the same one-sided bound then applies, and the ratio is printed above.
    lagging = connection == "usb" or report["executed_motion_ratio"] < EXECUTED_FULLY

    def close(hw_value: float, sim_value: float, what: str, tol: float = 0.02) -> None:
        if lagging and what != "joint_limits":
            assert hw_value >= sim_value - tol, what
        else:
            assert hw_value == pytest.approx(sim_value, abs=tol), what

    sim_true = [d for d in sim_reference["sim"]["min_obstacle_distance_m"] if d is not None]
    sim_true_margin = min(sim_true) - OBSTACLE_SAFETY_M
    measurement_error = abs(sim_reference["measured"]["obstacles"]["safety_margin_min"] - sim_true_margin)
    for key, ref in (("joint_limits", sim_reference["sim"]), ("obstacles", sim_reference["measured"])):
        h, m = hw[key], ref[key]
        print(f"{key}: hardware path {_fmt(h)}; simulation {_fmt(m)}")
        tol = 0.02 + (measurement_error if key == "obstacles" else 0.0)
        close(h["safety_margin_min"], m["safety_margin_min"], key, tol)
        assert h["physical_margin_min"] > 0.0 and m["physical_margin_min"] > 0.0, key
    # Ground truth over the run's own window (after it the arm stands still while the person's
    # script goes on in the stand-in).
    in_run = [d for t, d in zip(rec["truth_t"], rec["truth_m"], strict=True) if t0 <= t <= t1]
    truth_min = [min(d[cp] for d in in_run) for cp in ("link_4", "link_6", "link_7")]
    print(f"min true distance [m]: hardware path {np.round(truth_min, 4).tolist()}, "
          f"simulation {np.round(sim_reference['sim']['min_obstacle_distance_m'], 4).tolist()}")  # fmt: skip
    for d_hw, d_sim in zip(truth_min, sim_reference["sim"]["min_obstacle_distance_m"], strict=True):
        if d_sim is not None and d_sim < 1.0:
            close(d_hw, d_sim, "true distance")
    # No failed step but a missed solver deadline (the wall-clock guard: this machine's load).
    print(f"steps {hw['status_steps']}, deadline misses {hw['deadline_misses']}, warm-up {hw['warmup_steps']}")
    assert hw["failures"] == hw["deadline_misses"] and hw["warmup_steps"] > 0

    # Watchdog: every trip logged with its cause; a joint-state trip only where the states really
    # stopped for the timeout (this machine's load), never on the driver model's own jitter.
    from compare.config import HardwareConfig

    timeout = report["state_timeout_s"]
    real_timeout = HardwareConfig(connection_type=connection).state_timeout_s  # the real default
    # The model's own jitter: its gaps, except those an in/start call made (startAPI's 50 ms sleep
    # on the driver's only thread, as the real driver does; the bridge's restart grace covers it).
    # A start after a watchdog trip (this machine's load) then pauses the states beyond the
    # Ethernet default of 50 ms by design.
    starts = [(c["requested_t"], c["done_t"]) for c in rec["services"] if c["name"] == "start"]
    jitter: list[float] = []
    for a, b in pairwise(model_t):
        during = [t_b - t_a for t_a, t_b in starts if a < t_b and t_a < b]
        if during:  # no longer than the call itself plus the model's own jitter
            assert b - a < max(during) + real_timeout, (a, b, starts)
        else:
            jitter.append(b - a)
    model_gaps = np.array(jitter)
    # A stand-in starved of CPU publishes late now and then (its thread waits for a core): then
    # the model's jitter is judged on its 99th percentile, not on the one gap the load made.
    starved = report["executed_motion_ratio"] < EXECUTED_FULLY and connection != "usb"
    assert (np.percentile(model_gaps, 99) if starved else model_gaps.max()) < real_timeout
    # A trip is justified when the bridge held no fresher state than the one it judged stale: the
    # first joint state that reached its callback after that one came at the trip or later (the
    # stand-in stopped publishing, or rospy's threads delivered late on a starved machine: the
    # stand-in's publish times tell which, printed). The age the trip reports is its own arithmetic.
    published = np.array(rec["joint_state_t"])
    for event in report["watchdog_events"]:
        assert event["message"].startswith("watchdog: ")
        if event["reason"] and event["reason"].startswith("joint state stale"):
            t_event = t0 + event["t_s"]
            last = published[published <= t_event]
            assert last.size, event
            age = re.search(r"last one (\d+) ms ago", event["reason"])
            assert age and float(age.group(1)) / 1e3 >= timeout - 0.001, event
            assert event["t_s"] - event["state_t_s"] == pytest.approx(float(age.group(1)) / 1e3, abs=0.001), event
            assert event["next_state_t_s"] is None or event["next_state_t_s"] >= event["t_s"], event
            cause = "publish gap" if t_event - last[-1] >= timeout - 0.005 else "late delivery"
            print(f"joint-state trip at {event['t_s']:.3f} s: {cause}")
    # in/start before the first motion, in/stop at the end (the driver left stopped, FIFO erased).
    services = _services(rec)
    assert services[0][0] == "start" and services[-1][0] == "stop"
    first_motion = min(c["arrival_t"] for c in rec["commands"] if any(c["deg_s"]))
    assert services[0][1] < first_motion
    assert [s["service"] for s in report["driver_services"]] == [name for name, _ in services]

    # The recorded streams replay offline through the same bridge (no arm, nothing published).
    replay_out = tmp_path / "replay"
    rep = _hw(ros_env, config, replay_out, "--replay", str(bag), "--no-plots")
    assert rep.returncode == 0, rep.stderr[-3000:]
    replayed = read_json(replay_out / "summary.json")["methods"]["tpik"]
    assert replayed["hardware"]["replay"] == [str(bag)] and replayed["hardware"]["driver_services"] == []
    assert replayed["hardware"]["calibration"]["residual_m"] < 0.02
    assert replayed["hardware"]["rates"]["joint_state"]["rate_hz"] == pytest.approx(
        _rate(rec["joint_state_t"], t0, t1), rel=0.25
    )
    assert replayed["steps"] > 50


def test_joint_state_stall_zeroes_the_velocity_and_stops_the_driver(ros_env, procs, case1_config, tmp_path):
    stall_at = 1.5
    standin, record = _standin(procs, ros_env, case1_config, tmp_path, "--stop-joint-states-after", str(stall_at))
    res = _hw(ros_env, case1_config, tmp_path / "hw", "--duration", "2.5", "--no-plots")
    rec = _stop(standin, record)
    assert res.returncode == 0, res.stderr[-4000:]
    report = read_json(tmp_path / "hw" / "summary.json")["methods"]["tpik"]["hardware"]
    timeout = report["state_timeout_s"]
    last_state = max(rec["joint_state_t"])
    t_zero, stays_zero = _first_zero_after(rec, last_state)
    reaction = t_zero - last_state
    print(f"\njoint-state watchdog: zero command {1e3 * reaction:.1f} ms after the last joint state "
          f"(timeout {1e3 * timeout:.0f} ms)")  # fmt: skip
    assert stays_zero and reaction < timeout + SANITY_S
    trips = [e for e in report["watchdog_events"] if "joint state stale" in (e["reason"] or "")]
    assert trips, report["watchdog_events"]
    age_ms, limit_ms = (float(x) for x in re.findall(r"(\d+) ms", trips[-1]["reason"])[:2])
    assert age_ms >= limit_ms  # never before its timeout
    # It judged the stand-in's last state and none came after it. The stand-in records a publish
    # time when publish() has returned, so that state arrives after the previous record (its
    # publish began then), possibly just before its own record.
    arrived = report["clock_start_monotonic_s"] + trips[-1]["state_t_s"]
    before_last = sorted(rec["joint_state_t"])[-2]
    assert before_last < arrived < last_state + SANITY_S, (before_last, arrived, last_state)
    assert trips[-1]["next_state_t_s"] is None, trips[-1]
    assert "watchdog: zero velocity" in res.stderr and "joint state stale" in res.stderr
    assert _stops_after(rec, last_state), _services(rec)  # in/stop on the trip


def test_depth_stall_zeroes_the_velocity_and_stops_the_driver(ros_env, procs, case1_config, tmp_path):
    stall_at = 1.5
    standin, record = _standin(procs, ros_env, case1_config, tmp_path, "--stop-depth-after", str(stall_at))
    res = _hw(ros_env, case1_config, tmp_path / "hw", "--duration", "2.5", "--no-plots")
    rec = _stop(standin, record)
    assert res.returncode == 0, res.stderr[-4000:]
    last_frame = max(rec["depth_t"])
    t_zero, stays_zero = _first_zero_after(rec, last_frame)
    reaction = t_zero - last_frame
    print(f"\ndepth stall: zero command {1e3 * reaction:.1f} ms after the last depth frame")
    # The loop's own stale-frame check (1.5 sensing periods) usually stops first; the 200 ms
    # watchdog of the command stream is the bound, and it calls in/stop.
    assert stays_zero and reaction < 0.2 + SANITY_S
    events = read_json(tmp_path / "hw" / "summary.json")["methods"]["tpik"]["hardware"]["watchdog_events"]
    assert any("depth stale" in (e["reason"] or "") for e in events), events
    assert "depth stale" in res.stderr
    assert _stops_after(rec, last_frame + 0.2), _services(rec)


def test_dry_run_publishes_nothing_and_calls_no_service(ros_env, procs, case1_config, tmp_path):
    config = _with_hardware(case1_config, "live_bg.toml", background_capture_s=0.5)
    text = config.read_text()
    config.write_text(re.sub(r'background_file = "[^"]*"\n', "", text))
    standin, record = _standin(procs, ros_env, config, tmp_path)
    res = _hw(ros_env, config, tmp_path / "hw", "--duration", "1", "--dry-run", "--no-plots")
    rec = _stop(standin, record)
    assert res.returncode == 0, res.stderr[-4000:]
    assert rec["command_t"] == [] and rec["services"] == []
    summary = read_json(tmp_path / "hw" / "summary.json")["methods"]["tpik"]
    assert summary["hardware"]["dry_run"] and summary["steps"] > 50
    # roscore with ROS_IP=127.0.0.1 and this node: loopback only; only the stand-in feeds the bridge.
    network = summary["hardware"]["network"]
    assert network["problems"] == [] and network["node_sockets"] == [] and not network["allowed"]
    assert network["master_sockets"] == [f"127.0.0.1:{ros_env['ROS_MASTER_URI'].rsplit(':', 1)[1]}"]
    assert summary["hardware"]["halt_cause"] is None and summary["hardware"]["ignored_messages"] == {}
    feeders = summary["hardware"]["publishers_at_start"]["/j2s7s300_driver/out/joint_state"]
    assert len(feeders) == 1 and feeders[0].startswith("/j2s7s300_driver_standin")  # (an anonymous node name)


def test_start_refused_outside_the_safety_thresholds(ros_env, procs, case1_config, tmp_path, jaco):
    q = jaco.home.copy()
    q[3] = jaco.q_lower[3] + 0.05  # joint 4 inside its physical limit, past the 0.1 rad safety margin
    text = case1_config.read_text().replace("[scenario]", f"[scenario]\nstart_q = {list(map(float, q))}", 1)
    config = tmp_path / "near_limit.toml"
    config.write_text(text)
    standin, record = _standin(procs, ros_env, config, tmp_path)
    res = _hw(ros_env, config, tmp_path / "hw", "--duration", "1", "--no-plots")
    rec = _stop(standin, record)
    assert res.returncode == 2
    assert "outside its safety thresholds" in res.stderr and "joint_limit_4" in res.stderr
    assert not np.any(rec["command_deg_s"])  # only zero velocity ever reached the driver
    assert [name for name, _ in _services(rec)] == ["stop"]  # never started; stopped on the way out


def test_start_refused_when_the_driver_publishes_at_10_hz(ros_env, procs, case1_config, tmp_path):
    standin, record = _standin(procs, ros_env, case1_config, tmp_path, "--feedback-publish-rate", "0.1")
    res = _hw(ros_env, case1_config, tmp_path / "hw", "--duration", "1", "--no-plots")
    _stop(standin, record)
    assert res.returncode == 2
    assert "feedback_publish_rate:=0.01" in _error_line(res.stderr)


def test_start_refused_when_the_watchdog_is_tighter_than_the_usb_jitter(ros_env, procs, case1_config, tmp_path):
    # The former default: 3 periods of 100 Hz = 30 ms, against a USB driver (45 Hz, gaps up to ~35 ms).
    config = _with_hardware(case1_config, "tight.toml", state_rate_hz=45.0, state_timeout_periods=1.35)
    standin, record = _standin(procs, ros_env, config, tmp_path, "--connection", "usb")
    res = _hw(ros_env, config, tmp_path / "hw", "--duration", "1", "--no-plots")
    _stop(standin, record)
    assert res.returncode == 2, res.stderr[-2000:]
    assert "joint states have gaps" in res.stderr and "stop and go" in res.stderr


def test_a_5_cm_camera_pose_error_is_refused_and_hw_check_reports_it(ros_env, procs, case1_config, tmp_path):
    from compare.hardware.conversions import transform_from_translation_quaternion
    from compare.hardware.standin import camera_calibration

    cal = camera_calibration()
    T = transform_from_translation_quaternion(cal["camera_translation_m"], cal["camera_quaternion_xyzw"])
    moved = (T[:3, 3] + 0.052 * T[:3, 0]).tolist()  # the RGB optical frame's origin taken for the IR one's
    text = case1_config.read_text()
    good = re.search(r"camera_translation_m = \[[^\]]*\]", text).group(0)  # type: ignore[union-attr]
    off = tmp_path / "off.toml"
    off.write_text(text.replace(good, f"camera_translation_m = {_toml(moved)}"))
    standin, record = _standin(procs, ros_env, case1_config, tmp_path)
    check_good = _hw(ros_env, case1_config, tmp_path, command="hw-check")
    check_off = _hw(ros_env, off, tmp_path, command="hw-check")
    res = _hw(ros_env, off, tmp_path / "hw", "--duration", "1", "--no-plots")
    rec = _stop(standin, record)
    print(f"\n{check_good.stdout.strip()}\n{check_off.stdout.strip()}")
    assert check_good.returncode == 0 and "calibration OK" in check_good.stdout, check_good.stderr[-2000:]
    assert check_off.returncode == 2 and "camera calibration off" in check_off.stderr
    assert res.returncode == 2 and "camera calibration off" in _error_line(res.stderr)
    assert not np.any(rec["command_deg_s"])


def test_sigint_ends_with_zero_velocity_in_stop_and_keeps_the_results(ros_env, procs, case1_config, tmp_path):
    standin, record = _standin(procs, ros_env, case1_config, tmp_path)
    out = tmp_path / "hw"
    hw = start(procs, ros_env, ["-m", "compare.cli", "hw", str(case1_config), "--out", str(out), "-q", "--no-plots",
                                "--duration", "20"], tmp_path / "hw.log")  # fmt: skip
    deadline = time.monotonic() + TIMEOUT_S
    while time.monotonic() < deadline and "hardware run" not in hw.output():  # the loop is starting
        time.sleep(0.1)
    time.sleep(1.0)
    t_sig = time.monotonic()
    hw.popen.send_signal(signal.SIGINT)
    assert hw.popen.wait(timeout=30) == 130, hw.output()[-3000:]
    rec = _stop(standin, record)
    t_zero, stays_zero = _first_zero_after(rec, t_sig)
    print(f"\nSIGINT: zero command {1e3 * (t_zero - t_sig):.1f} ms after the signal")
    assert stays_zero and t_zero - t_sig < SANITY_S
    assert _stops_after(rec, t_sig), _services(rec)
    summary = read_json(out / "summary.json")["methods"]["tpik"]
    assert summary["interrupted"] == "SIGINT" and summary["steps"] > 10


@pytest.mark.parametrize("which", ["command", "joint_state"])
def test_a_second_publisher_halts_the_arm_within_one_watchdog_period(ros_env, procs, case1_config, tmp_path, which):
    """A node registering on the driver's command topic (or on the joint states the bridge reads)
    halts the run: zero velocity, then ``in/stop``; the cause is in the results. It is found by the
    first poll of the master after its registration (polls every half watchdog period)."""
    hw_cfg = tomllib.loads(case1_config.read_text())["hardware"]
    topic, msg_type = (
        (hw_cfg.get("velocity_topic", "/j2s7s300_driver/in/joint_velocity"), "JointVelocity")
        if which == "command"
        else (hw_cfg.get("joint_state_topic", "/j2s7s300_driver/out/joint_state"), "JointState")
    )
    standin, record = _standin(procs, ros_env, case1_config, tmp_path)
    out = tmp_path / "hw"
    hw = start(procs, ros_env, ["-m", "compare.cli", "hw", str(case1_config), "--out", str(out), "-q", "--no-plots",
                                "--duration", "20"], tmp_path / "hw.log")  # fmt: skip
    deadline = time.monotonic() + TIMEOUT_S
    while time.monotonic() < deadline and "hardware run" not in hw.output():  # the loop is starting
        assert hw.popen.poll() is None, hw.output()[-3000:]
        time.sleep(0.1)
    time.sleep(1.0)
    foreign_record = tmp_path / "foreign.json"
    start(procs, ros_env, ["-m", "tests.hardware.foreign_publisher", topic, msg_type, "--record", str(foreign_record)],
          tmp_path / "foreign.log")  # fmt: skip
    assert hw.popen.wait(timeout=TIMEOUT_S) == 3, hw.output()[-3000:]  # halted, results written
    rec = _stop(standin, record)
    foreign = read_json(foreign_record)
    caller = foreign["caller_id"]
    cause = f"foreign command publisher {caller}" if which == "command" else f"second publisher {caller} on {topic}"
    assert f"halted: {cause}" in hw.output()
    report = read_json(out / "summary.json")["methods"]["tpik"]["hardware"]
    assert report["halt_cause"] == cause
    watch = report["publisher_watch"]
    assert watch["cause"] == cause and watch["failed_polls"] == 0
    t0 = report["clock_start_monotonic_s"]
    registered = foreign["registered_t"]
    found = t0 + watch["cause_t_s"]  # start of the poll that found it
    timeout = report["state_timeout_s"]
    assert watch["period_s"] == pytest.approx(timeout / 2)
    # The stand-in saw the halt: the command stream ends in zeros after the registration, then in/stop.
    t_zero, stays_zero = _first_zero_after(rec, foreign["before_t"])
    stops = _stops_after(rec, foreign["before_t"])
    print(f"\n{which}: found {1e3 * (found - registered):.0f} ms after the registration (poll period "
          f"{1e3 * watch['period_s']:.0f} ms, max poll interval {watch['poll_interval_max_ms']:.0f} ms); "
          f"zero at the driver {1e3 * (t_zero - registered):.0f} ms, in/stop requested "
          f"{1e3 * (stops[0] - registered):.0f} ms after it (watchdog period {1e3 * timeout:.0f} ms)")  # fmt: skip
    assert stays_zero and stops, _services(rec)
    # Found by the first or second poll after it (the second when one was in flight at registration).
    assert found - registered <= 2 * watch["period_s"] + SANITY_S
    assert t_zero - registered < timeout + SANITY_S and stops[0] - registered < timeout + SANITY_S
    assert report["driver_services"][-1]["service"] == "stop" and report["driver_services"][-1]["cause"] == cause

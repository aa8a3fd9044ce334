"""Velocity/acceleration clamps, watchdog and start checks (no ROS needed)."""

from __future__ import annotations

import numpy as np
import pytest

from compare.hardware.ros_env import JOINT_VELOCITY_MD5, joint_velocity_definition
from compare.hardware.safety import CommandLimiter, Watchdog, start_problems
from tpik.hierarchy import Hierarchy

V_MAX = np.full(7, 0.6)


def test_velocity_clamp_keeps_the_direction():
    lim = CommandLimiter(V_MAX, a_max=1e6, dt=0.01)
    out, why = lim.apply(np.array([1.2, 0.3, 0, 0, 0, 0, 0]), np.zeros(7))
    np.testing.assert_allclose(out[:2], [0.6, 0.15])
    assert "velocity" in why


def test_acceleration_clamp_limits_the_change_per_period():
    lim = CommandLimiter(V_MAX, a_max=2.0, dt=0.01)
    prev = np.zeros(7)
    out, why = lim.apply(np.full(7, 0.5), prev)
    assert np.max(np.abs(out - prev)) == pytest.approx(0.02)
    assert "acceleration" in why


def test_zero_always_passes_at_once_and_garbage_becomes_zero():
    lim = CommandLimiter(V_MAX, a_max=0.1, dt=0.01)
    out, why = lim.apply(np.zeros(7), np.full(7, 0.5))
    assert not np.any(out) and why is None
    out, why = lim.apply(np.array([np.nan, 0, 0, 0, 0, 0, 0]), np.zeros(7))
    assert not np.any(out) and "finite" in why
    out, why = lim.apply(np.zeros(3), np.zeros(7))
    assert not np.any(out) and "shape" in why


def test_watchdog_trips_on_stale_state_depth_or_loop_and_logs_each_change_once():
    wd = Watchdog(state_timeout_s=0.03, depth_timeout_s=0.2, command_timeout_s=0.03)
    assert wd.check(1.0, 0.995, 0.95, 0.99) is None
    assert "joint state stale" in wd.check(1.04, 1.0, 0.95, 1.03)
    assert "joint state stale" in wd.check(1.05, 1.0, 0.95, 1.04)  # same cause: no new event
    assert wd.check(1.06, 1.055, 0.95, 1.05) is None
    assert "depth stale" in wd.check(1.2, 1.19, 0.95, 1.19)
    assert "stalled" in wd.check(1.3, 1.29, 1.25, 1.2)
    assert [e.reason is None for e in wd.events] == [False, True, False, False]
    assert all(e.message.startswith("watchdog: ") for e in wd.events)
    # Each event keeps the arrival of the state it judged (the bridge reports what came next).
    assert [e.state_t_s for e in wd.events] == [1.0, 1.055, 1.19, 1.29]


def test_watchdog_without_depth_ignores_depth():
    wd = Watchdog(state_timeout_s=0.03, depth_timeout_s=None, command_timeout_s=0.03)
    assert wd.check(1.0, 0.99, None, 0.99) is None


def test_start_refused_outside_safety_thresholds(jaco):
    h = Hierarchy.from_description(
        [{"name": "jl", "tasks": [{"type": "joint_limit", "joints": [2], "safety_margin": 0.1}]}], jaco
    )
    assert start_problems(h, jaco.kinematics(jaco.home)) == []
    q = jaco.home.copy()
    q[1] = jaco.q_lower[1] + 0.05  # inside the physical limit, past the safety threshold
    problems = start_problems(h, jaco.kinematics(q))
    assert len(problems) == 1 and "outside its safety thresholds" in problems[0]


def test_our_joint_velocity_definition_is_the_drivers():
    # kinova_msgs/msg/JointVelocity.msg: seven float32 joint1..joint7; ROS hashes the text.
    import hashlib

    text = joint_velocity_definition()
    assert text.split() == [w for i in range(1, 8) for w in ("float32", f"joint{i}")]
    assert hashlib.md5(text.strip().encode()).hexdigest() == JOINT_VELOCITY_MD5


def test_the_bridge_records_each_verdicts_next_joint_state_when_it_arrives_not_from_its_bounded_log(monkeypatch):
    """``next_state_t_s`` of a trip is the first arrival after the state it judged, even when
    the bridge's bounded arrival log (the measured rates) no longer reaches back to it."""
    from types import SimpleNamespace

    from compare.config import HardwareConfig
    from compare.hardware import ros_io

    clock = [100.0]
    monkeypatch.setattr(ros_io.time, "monotonic", lambda: clock[0])
    hw = HardwareConfig(joint_names=tuple(f"joint_{i}" for i in range(1, 8)))
    io = ros_io.RosRobotIO(hw, V_MAX, 0.01, use_depth=False, dry_run=True)  # bookkeeping only, no ROS node
    unstamped = SimpleNamespace(stamp=SimpleNamespace(to_sec=lambda: 0.0))
    io.rates["joint_state"] = ros_io._RateCounter(maxlen=3)  # a log far shorter than the run
    io.start_clock()

    def state_at(t: float) -> None:
        clock[0] = 100.0 + t
        io._on_joint_state(
            SimpleNamespace(name=list(hw.joint_names), position=[0.0] * 7, velocity=[], header=unstamped)
        )

    def check_at(t: float) -> None:
        clock[0] = 100.0 + t
        with io._lock:
            io.watchdog.check(*io._times(clock[0]))

    io._command_t = None
    state_at(0.00)
    check_at(0.005)  # no command yet: the first verdict judges the state of t = 0
    for k in range(1, 5):
        state_at(0.01 * k)
        io._command_t = clock[0]
        check_at(0.01 * k + 0.001)  # recovered at the first check with a command
    check_at(0.2)  # stale: judged the state of t = 0.04, trips
    for k in range(10):  # states resume, many more than the log keeps
        state_at(0.25 + 0.01 * k)
    events = io._event_report()
    trip = next(e for e in events if e["reason"] and "joint state stale" in e["reason"])
    assert trip["state_t_s"] == pytest.approx(0.04)
    assert trip["next_state_t_s"] == pytest.approx(0.25)  # the log kept only 0.32–0.34
    assert events[0]["state_t_s"] == pytest.approx(0.0) and events[0]["next_state_t_s"] == pytest.approx(0.01)
    io._command_t = 100.345
    check_at(0.345)  # recovered: judged the state of t = 0.34
    check_at(0.5)  # stale again, and nothing arrives after it
    *_, recovery, last = io._event_report()
    assert recovery["reason"] is None and last["reason"] and "joint state stale" in last["reason"]
    assert recovery["next_state_t_s"] is None and last["state_t_s"] == pytest.approx(0.34)
    assert last["next_state_t_s"] is None

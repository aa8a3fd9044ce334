"""Depth sensing on "live" frames (no ROS): the hardware composition agrees with the simulation's pipeline."""

from __future__ import annotations

import collections
import itertools
import math
import os
import threading
from pathlib import Path

import mujoco
import numpy as np
import pytest

from compare.config import PersonKeyframe, load_config
from compare.hardware.exceptions import HardwareError
from compare.hardware.sensing import (
    HardwareDepthSensing,
    capture_background,
    load_background,
    save_background,
    static_background,
)
from compare.sensing.frames import DepthFrame

pytestmark = [
    pytest.mark.rendering,
    pytest.mark.skipif(
        mujoco.GLContext.__module__.endswith("glfw") and not os.environ.get("DISPLAY"),
        reason="offscreen rendering needs MUJOCO_GL=egl before mujoco is imported (the Makefile exports it)",
    ),
]

CONFIG = Path(__file__).resolve().parents[2] / "configs" / "case1.toml"


@pytest.fixture(scope="module")
def scene(jaco):
    from compare.sensing.person import Person
    from compare.sensing.pipeline import DepthPipeline, DepthSensingSettings
    from compare.sensing.scene import load_workcell, make_data

    config, _ = load_config(CONFIG)
    model = load_workcell()
    pipeline = DepthPipeline(model, DepthSensingSettings.from_sensor_config(config.sensor))
    q = jaco.home.copy()
    data = make_data(model, q)
    Person(model, []).apply(0.0, data)
    mujoco.mj_forward(model, data)
    empty = pipeline.render(data, stamp_s=0.0)
    # The paper's case 1: the person steps in with the right hand raised into the EE's path.
    key = PersonKeyframe(t=0.0, position=(0.05, 0.95), yaw=-1.5708, right_hand=(0.0, 0.62, 0.75))
    Person(model, [key]).apply(0.0, data)
    mujoco.mj_forward(model, data)
    person = pipeline.render(data, stamp_s=1.0)
    yield config, pipeline, data, q, empty, person
    pipeline.close()


def _stream(frame: DepthFrame):
    counter = itertools.count(1)
    return lambda: DepthFrame(frame.depth_m, frame.stamp_s + 1e-3 * next(counter), frame.camera)


def test_hardware_sensing_matches_the_simulation_pipeline(scene, jaco):
    from compare.sensing.scene import control_point_positions

    config, pipeline, data, q, empty, person = scene
    kin = jaco.kinematics(q)
    sim = pipeline.process(person, control_point_positions(kin, jaco.control_points), data=data)
    depth = capture_background(_stream(empty), lambda t: q, jaco, config, duration_s=0.05)
    assert depth is not None
    background = static_background(depth, config)
    hw = HardwareDepthSensing(jaco, pipeline.camera, lambda: person, lambda t: q, config, background)
    result = hw.update(1.0, kin)
    assert not result.blind
    near = [cp for cp, r in sim.readings.items() if r.in_range]
    assert near, "the person should be within ρ of a control point"
    for cp in sim.readings:
        d_sim, d_hw = sim.readings[cp].distance_m, result.readings[cp].distance_m
        if math.isfinite(d_sim):
            assert d_hw == pytest.approx(d_sim, abs=0.02), cp
        else:
            assert not math.isfinite(d_hw) or d_hw > config.sensor.rho_m * 0.9, cp


def test_empty_scene_gives_nothing_in_range(scene, jaco):
    config, pipeline, _, q, empty, _ = scene
    depth = capture_background(_stream(empty), lambda t: q, jaco, config, duration_s=0.05)
    background = static_background(depth, config)
    hw = HardwareDepthSensing(jaco, pipeline.camera, lambda: empty, lambda t: q, config, background)
    result = hw.update(0.0, jaco.kinematics(q))
    assert not result.blind
    assert not any(r.in_range for r in result.readings.values())


def test_stale_or_missing_frame_is_blind(scene, jaco):
    config, pipeline, _, q, _, person = scene
    kin = jaco.kinematics(q)
    hw = HardwareDepthSensing(jaco, pipeline.camera, lambda: person, lambda t: q, config)
    assert not hw.update(person.stamp_s + 0.1, kin).blind
    assert hw.update(person.stamp_s + config.sensor.max_age_s + 0.01, kin).blind
    assert HardwareDepthSensing(jaco, pipeline.camera, lambda: None, lambda t: q, config).update(0.0, kin).blind
    assert np.isfinite(hw.filter_time_s)


def test_captured_background_leaves_the_arm_out_and_round_trips(scene, jaco, tmp_path):
    config, pipeline, _, q, empty, _ = scene
    depth = capture_background(_stream(empty), lambda t: q, jaco, config, duration_s=0.05)
    raw_valid = empty.depth_m > 0
    arm = raw_valid & (depth == 0)  # valid returns without background: the arm's pixels
    assert 0 < np.count_nonzero(arm) < 0.2 * arm.size
    # The static scene (table, floor) is the background everywhere else.
    assert np.count_nonzero(depth > 0) > 0.5 * np.count_nonzero(raw_valid)
    path = tmp_path / "bg.npz"
    save_background(path, depth)
    np.testing.assert_array_equal(load_background(path, pipeline.camera), depth)
    small = type(pipeline.camera)(**{**pipeline.camera.__dict__, "width": 10})
    with pytest.raises(HardwareError, match="px"):
        load_background(path, small)


def test_self_filter_poses_span_the_latency_in_small_steps():
    from compare.hardware.sensing import SWEEP_MAX_POSES, SWEEP_STEP_RAD, self_filter_poses

    q0, q1 = np.zeros(7), np.array([0.0, 0.1, 0.0, -0.05, 0.0, 0.0, 0.0])
    poses = self_filter_poses(q0, q1)
    assert np.array_equal(poses[0], q0) and np.allclose(poses[-1], q1)
    assert max(np.max(np.abs(b - a)) for a, b in itertools.pairwise(poses)) <= SWEEP_STEP_RAD + 1e-12
    assert len(self_filter_poses(q0, q0)) == 1 and len(self_filter_poses(None, q1)) == 1
    assert len(self_filter_poses(q0, q0 + 3.0)) == SWEEP_MAX_POSES  # a long gap: bounded work


def test_a_moving_arm_leaves_no_phantom_when_the_joint_state_lags_the_frame(scene, jaco):
    """The frame shows the arm between the last state that had arrived and the newest one."""
    from compare.sensing.person import Person
    from compare.sensing.scene import make_data

    config, pipeline, _, q, empty, _ = scene
    depth = capture_background(_stream(empty), lambda t: q, jaco, config, duration_s=0.05)
    background = static_background(depth, config)
    q_lag = q.copy()
    q_new = q + np.array([0.0, 0.3, 0.0, 0.3, 0.0, 0.3, 0.0])  # ~0.3 rad of joint motion in the latency
    data = make_data(pipeline.model, 0.5 * (q_lag + q_new))  # the arm as the camera saw it
    Person(pipeline.model, []).apply(0.0, data)
    mujoco.mj_forward(pipeline.model, data)
    frame = pipeline.render(data, stamp_s=1.0)
    swept = HardwareDepthSensing(jaco, pipeline.camera, lambda: frame, lambda t: q_lag, config, background)
    result = swept.update(1.0, jaco.kinematics(q_new))
    assert not result.blind and not any(r.in_range for r in result.readings.values()), result.readings
    # Filtering the lagging pose only (as before) leaves part of the arm in the image: a phantom.
    only_lag = HardwareDepthSensing(jaco, pipeline.camera, lambda: frame, lambda t: q_lag, config, background)
    phantom = only_lag.update(1.0, jaco.kinematics(q_lag))
    assert any(r.in_range for r in phantom.readings.values())


def test_a_frame_newer_than_every_joint_state_is_filtered_up_to_the_extrapolated_pose(scene, jaco):
    """No state newer than the frame (USB states at 45 Hz, frames at 30 Hz): the arm in the image is
    past the newest state; the sweep to the extrapolated pose removes it, q_now alone does not."""
    from compare.sensing.person import Person
    from compare.sensing.scene import make_data

    config, pipeline, _, q, empty, _ = scene
    depth = capture_background(_stream(empty), lambda t: q, jaco, config, duration_s=0.05)
    background = static_background(depth, config)
    q_ahead = q + np.array([0.0, 0.3, 0.0, 0.3, 0.0, 0.3, 0.0])
    data = make_data(pipeline.model, q_ahead)  # the arm as the camera saw it, ahead of every state
    Person(pipeline.model, []).apply(0.0, data)
    mujoco.mj_forward(pipeline.model, data)
    frame = pipeline.render(data, stamp_s=1.0)
    kin = jaco.kinematics(q)  # the newest state is the one the frame was matched with
    stale = HardwareDepthSensing(jaco, pipeline.camera, lambda: frame, lambda t: q, config, background)
    assert any(r.in_range for r in stale.update(1.0, kin).readings.values())
    ahead = HardwareDepthSensing(
        jaco, pipeline.camera, lambda: frame, lambda t: q, config, background, q_ahead=lambda t: q_ahead
    )
    result = ahead.update(1.0, kin)
    assert not result.blind and not any(r.in_range for r in result.readings.values()), result.readings


def test_self_filter_poses_continue_past_the_newest_state_within_the_pose_budget():
    from compare.hardware.sensing import SWEEP_MAX_POSES, SWEEP_STEP_RAD, self_filter_poses

    q0, q1, q2 = np.zeros(7), np.full(7, 0.05), np.full(7, 0.09)
    poses = self_filter_poses(q0, q1, q2)
    assert np.array_equal(poses[0], q0) and np.allclose(poses[-1], q2)
    assert any(np.allclose(p, q1) for p in poses)  # the newest state is on the path
    assert max(np.max(np.abs(b - a)) for a, b in itertools.pairwise(poses)) <= SWEEP_STEP_RAD + 1e-12
    long = self_filter_poses(q0, q0 + 3.0, q0 + 3.01)
    assert len(long) <= SWEEP_MAX_POSES and np.allclose(long[-1], q0 + 3.01)


def _stamped(t_wall: float):
    from types import SimpleNamespace

    return SimpleNamespace(stamp=SimpleNamespace(to_sec=lambda: t_wall))


def test_a_header_stamp_is_taken_only_when_it_lies_on_this_clock(monkeypatch):
    from types import SimpleNamespace

    from compare.hardware import ros_io

    monkeypatch.setattr(ros_io.time, "monotonic", lambda: 50.0)
    monkeypatch.setattr(ros_io.time, "time", lambda: 1050.0)  # wall = monotonic + 1000 s
    arrival = 50.0
    on_clock = ros_io.stamp_on_this_clock
    assert on_clock(SimpleNamespace(header=_stamped(1049.85)), arrival) == pytest.approx(49.85)
    assert on_clock(SimpleNamespace(header=_stamped(1050.004)), arrival) == arrival  # never after arrival
    assert on_clock(SimpleNamespace(header=_stamped(1050.1)), arrival) is None  # ahead: another clock
    assert on_clock(SimpleNamespace(header=_stamped(1049.4)), arrival) is None  # replayed / unsynced
    assert on_clock(SimpleNamespace(header=_stamped(0.0)), arrival) is None  # unset stamp
    assert on_clock(SimpleNamespace(), arrival) is None  # no header


def test_joint_states_delivered_late_keep_their_stamps_for_the_self_filter(monkeypatch):
    """A starved rospy thread delivers joint states late: the self-filter must place the arm by
    the states' own stamps. By arrival, a frame taken during the starved spell would be matched
    with a state 150 ms old and extrapolated by only the 5 ms since the late state came, leaving
    the arm's newer position in the image (a phantom obstacle on the arm itself)."""
    from types import SimpleNamespace

    from compare.config import HardwareConfig
    from compare.hardware import ros_io

    clock = [100.0]
    monkeypatch.setattr(ros_io.time, "monotonic", lambda: clock[0])
    monkeypatch.setattr(ros_io.time, "time", lambda: clock[0] + 1000.0)
    hw = HardwareConfig(joint_names=tuple(f"joint_{i}" for i in range(1, 8)))
    io = ros_io.RosRobotIO(hw, np.full(7, 0.6), 0.01, use_depth=False, dry_run=True)
    io.start_clock()
    io._sent = np.full(7, 0.5)  # the arm moves at 0.5 rad/s per joint

    def state(stamp_t: float, arrival_t: float) -> None:
        clock[0] = 100.0 + arrival_t
        msg = SimpleNamespace(
            name=list(hw.joint_names), position=[0.5 * stamp_t] * 7, velocity=[], header=_stamped(1100.0 + stamp_t)
        )
        io._on_joint_state(msg)

    for k in range(11):  # on time: 0.00 … 0.10 s
        state(0.01 * k, 0.01 * k + 0.001)
    for k in range(11, 26):  # published 0.11 … 0.25 s, all delivered at once at 0.26 s
        state(0.01 * k, 0.26)
    np.testing.assert_allclose(io.q_at(0.255), 0.5 * 0.25)  # by arrival: 0.5 · 0.10, the arm 150 ms back
    lag = io.rates["joint_state"].stats()  # the report shows how late they came
    assert lag["delivery_lag_max_ms"] == pytest.approx(150.0) and lag["count"] == 26
    # The newest state came late (stamped 0.10 s, delivered at 0.25 s; rospy's queue of 1 dropped the rest),
    # on a fresh bridge (this one's stamp check would drop stamps going back to 0):
    io = ros_io.RosRobotIO(hw, np.full(7, 0.6), 0.01, use_depth=False, dry_run=True)
    io.start_clock()
    io._sent = np.full(7, 0.5)
    for k in range(10):
        state(0.01 * k, 0.01 * k + 0.001)
    state(0.10, 0.25)
    io._capture_of = {round(100.255, 6): 100.255}  # a frame taken at 0.255 s
    lead = min(0.255 - (0.10 - 0.01), ros_io.MAX_FRAME_LEAD_S)  # by arrival: 0.255 − (0.25 − 0.01) = 0.015 s
    np.testing.assert_allclose(io.frame_q_ahead(0.255), 0.5 * 0.10 + 0.5 * lead, atol=1e-9)


def test_frame_q_ahead_extrapolates_the_newest_state_with_the_velocity_sent():
    """lead = t_capture − (t_state − T), clipped to [0, MAX_FRAME_LEAD_S]; q_s + q̇_sent · lead."""
    from compare.hardware.ros_io import MAX_FRAME_LEAD_S, RosRobotIO

    io = RosRobotIO.__new__(RosRobotIO)  # the bookkeeping only: no ROS node
    io._lock, io._epoch = threading.RLock(), 100.0
    io._history = collections.deque((100.0 + 0.022 * k, np.full(7, 0.01 * k)) for k in range(10))
    io._sent = np.full(7, 0.5)
    newest_t = 100.0 + 0.022 * 9
    io._capture_of = {round(newest_t + 0.010, 6): newest_t + 0.010}  # captured 10 ms after the newest state
    ahead = io.frame_q_ahead(newest_t + 0.010 - 100.0)
    np.testing.assert_allclose(ahead, 0.09 + 0.5 * (0.010 + 0.022), atol=1e-9)
    io._capture_of = {}  # unknown capture: the arrival; a frame long after the state is capped
    np.testing.assert_allclose(io.frame_q_ahead(newest_t + 1.0 - 100.0), 0.09 + 0.5 * MAX_FRAME_LEAD_S, atol=1e-9)
    io._sent = np.zeros(7)  # a still command: no extrapolation
    np.testing.assert_allclose(io.frame_q_ahead(newest_t - 100.0), 0.09, atol=1e-12)
    io._history = collections.deque([(100.0, np.zeros(7))])
    assert io.frame_q_ahead(0.0) is None

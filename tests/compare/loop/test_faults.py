"""Fault injection: every kind, every method, the loop's safe reaction measured from the per-step table.

Scenario: case 1's hierarchy and person (standing near, outside activation) with the arm driving
to the far waypoint p¹, so it is moving when a fault hits; geometric sensing (the depth-mode
counterpart is the rendering test at the end). A fault window is 0.5–0.8 s.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

import robots
from compare.config import ConfigError, load_config, parse_config
from compare.loop.closed_loop import sensing_problem
from compare.loop.faults import FRAME_KINDS, FaultInjector
from compare.run import run_method
from compare.sensing.results import DistanceResult, ObstacleReading

CONFIGS = Path(__file__).resolve().parents[3] / "configs"
METHODS = ("tpik", "hqp-daqp", "mink")
PERIOD_S = 1.0 / 30.0
DT = 0.01
START, END = 0.5, 0.8


@pytest.fixture(scope="module")
def robot() -> robots.Robot:
    return robots.load("jaco2")


def _config(faults: list[dict], sensing: str = "geometric", duration: float = 1.2, methods=METHODS):
    config, _ = load_config(CONFIGS / "case1.toml")
    data = config.model_dump(mode="python")
    data["scenario"].update(duration_s=duration, time_scale=1.0, sensing=sensing)
    data["methods"] = {"names": list(methods), "settings": {}}
    data["faults"] = {"inject": faults}
    return parse_config(data)


def _qdot(steps) -> np.ndarray:
    cols = sorted((c for c in steps.columns if c.startswith("qdot_")), key=lambda c: int(c.split("_")[1]))
    return steps[cols].to_numpy(dtype=float)


def _check_commands(result: dict, robot: robots.Robot) -> None:
    qdot = _qdot(result["steps"])
    assert np.all(np.isfinite(qdot))
    assert np.all(np.abs(qdot) <= robot.v_max * (1 + 1e-6) + 1e-9)
    assert result["summary"]["unsafe_commands"] == 0


FRAME_FAULTS = {
    "depth_nan": {},
    "depth_zero": {},
    "depth_dropout": {"fraction": 0.9},
    "depth_frozen": {},
    "depth_delay": {"delay_s": 0.1},
}


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("kind", list(FRAME_FAULTS))
def test_faulty_depth_stream_stops_the_arm_within_one_depth_period(robot, method, kind):
    spec = {"kind": kind, "start_s": START, "end_s": END, **FRAME_FAULTS[kind]}
    result = run_method(_config([spec], methods=[method]), method, robot)
    steps, summary = result["steps"], result["summary"]
    _check_commands(result, robot)
    f = summary["faults"][kind]
    assert f["reaction"] == "safe_stop", f
    # Zero velocity within one depth period of the first faulty frame (at that very update for
    # blind, invalid or late frames; a frozen frame is stale once 1.5 periods old)...
    assert f["reaction_latency_s_max"] <= PERIOD_S + 1e-9
    # ... and from the onset: the next camera frame (≤ one period, on the 10 ms control grid),
    # plus the half period + one step a frozen frame needs to become overdue.
    slack = 0.5 * PERIOD_S + DT if kind == "depth_frozen" else 0.0
    assert f["reaction_latency_from_start_s_max"] <= PERIOD_S + DT + slack + 1e-9
    assert f["moving_steps_while_faulty"] == 0
    t = steps["t"].to_numpy()
    qdot = _qdot(steps)
    first = f["first_injected_t_s"]
    before = np.flatnonzero(t < first - 1e-9)[-1]
    assert np.max(np.abs(qdot[before])) > 1e-2, "the arm must be moving when the fault hits"
    react = np.flatnonzero(t >= first + f["reaction_latency_s_max"] - 1e-9)[0]
    assert np.all(qdot[react] == 0.0)
    # The reason is logged per step and as an event.
    assert "sensing:" in steps["reason"].iloc[react]
    assert any("safe stop" in e for e in summary["events"])
    # After the window the arm moves again.
    assert np.max(np.abs(qdot[t > END + 0.2])) > 1e-2
    assert steps[f"fault:{kind}"].any()


@pytest.mark.parametrize("offset", [0.001, 0.011, 0.021, 0.031])
@pytest.mark.parametrize("kind", list(FRAME_FAULTS))
def test_reaction_latency_bounds_hold_for_any_onset_phase(robot, kind, offset):
    start = START + offset  # between camera frames: the worst phase is just after a frame
    spec = {"kind": kind, "start_s": start, "end_s": start + 0.3, **FRAME_FAULTS[kind]}
    f = run_method(_config([spec], methods=["tpik"]), "tpik", robot)["summary"]["faults"][kind]
    assert f["reaction"] == "safe_stop"
    assert f["reaction_latency_s_max"] <= PERIOD_S + 1e-9
    slack = 0.5 * PERIOD_S + DT if kind == "depth_frozen" else 0.0
    assert f["reaction_latency_from_start_s_max"] <= PERIOD_S + DT + slack + 1e-9


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("kind", ["solver_fail", "solver_timeout"])
def test_solver_fault_triggers_the_fallback_in_the_same_step(robot, method, kind):
    spec = {"kind": kind, "start_s": START, "end_s": END, "every_n": 3}
    result = run_method(_config([spec], methods=[method]), method, robot)
    steps, summary = result["steps"], result["summary"]
    _check_commands(result, robot)
    f = summary["faults"][kind]
    assert f["reaction"] == "fallback"
    assert f["reaction_latency_s_max"] == 0.0
    assert f["injected_steps"] == f["fallback_steps"] == 10  # 30 steps, every third
    hit = steps[f"fault:{kind}"].to_numpy()
    assert np.all(steps["fallback"].to_numpy()[hit])
    assert np.all(_qdot(steps)[hit] == 0.0)  # fallback "zero"
    assert all("fallback:" in r for r in steps["reason"][hit])
    assert summary["failures"] >= 10


@pytest.mark.parametrize("method", METHODS)
def test_joint_noise_is_tolerated_and_commands_stay_safe(robot, method):
    spec = {"kind": "joint_noise", "start_s": START, "end_s": END, "std_rad": 0.01, "std_rad_s": 0.05}
    result = run_method(_config([spec], methods=[method]), method, robot)
    _check_commands(result, robot)
    f = result["summary"]["faults"]["joint_noise"]
    assert f["reaction"] == "tolerated" and f["injected_steps"] == 30


def test_short_delay_and_partial_dropout_are_tolerated(robot):
    faults = [
        {"kind": "depth_delay", "start_s": 0.3, "end_s": 0.6, "delay_s": 0.03},
        {"kind": "depth_dropout", "start_s": 0.7, "end_s": 0.9, "fraction": 0.2},
    ]
    result = run_method(_config(faults, methods=["tpik"]), "tpik", robot)
    f = result["summary"]["faults"]
    assert f["depth_delay"]["reaction"] == "tolerated"
    assert f["depth_dropout"]["reaction"] == "tolerated"
    assert not result["steps"]["blind"].any()


def test_the_same_faults_hit_every_method_at_the_same_steps(robot):
    faults = [
        {"kind": "depth_dropout", "start_s": 0.2, "end_s": 0.4, "fraction": 0.95},
        {"kind": "joint_noise", "start_s": 0.5, "end_s": 0.7},
        {"kind": "solver_fail", "start_s": 0.8, "end_s": 0.9, "every_n": 2},
    ]
    config = _config(faults, methods=["tpik", "hqp-daqp"])
    a = run_method(config, "tpik", robot)["steps"]
    b = run_method(config, "hqp-daqp", robot)["steps"]
    for kind in ("depth_dropout", "joint_noise", "solver_fail"):
        np.testing.assert_array_equal(a[f"fault:{kind}"], b[f"fault:{kind}"])


def test_noise_draws_are_seeded_per_fault_and_scenario():
    from compare.config import FaultsConfig

    cfg = FaultsConfig.model_validate({"inject": [{"kind": "joint_noise"}, {"kind": "depth_dropout"}]})
    one = FaultInjector(cfg, seed=3, time_scale=1.0, clock=lambda: 0.0)
    two = FaultInjector(cfg, seed=3, time_scale=1.0, clock=lambda: 0.0)
    other = FaultInjector(cfg, seed=4, time_scale=1.0, clock=lambda: 0.0)
    w = one.windows[0]
    assert np.array_equal(one.rng(w).normal(size=5), two.rng(two.windows[0]).normal(size=5))
    assert not np.array_equal(one.rng(w).normal(size=5), other.rng(other.windows[0]).normal(size=5))
    assert not np.array_equal(one.rng(w).normal(size=5), one.rng(one.windows[1]).normal(size=5))


def test_no_faults_means_no_wrappers():
    from compare.config import FaultsConfig

    inj = FaultInjector(FaultsConfig(), seed=0, time_scale=1.0, clock=lambda: 0.0)
    sentinel = object()
    assert inj.wrap_io(sentinel) is sentinel  # type: ignore[arg-type]
    assert inj.wrap_obstacles(sentinel) is sentinel  # type: ignore[arg-type]
    assert inj.wrap_solver(sentinel) is sentinel  # type: ignore[arg-type]


def _result(blind=False, stamp=1.0, distance=0.4, point=(0.0, 0.0, 1.0)):
    reading = ObstacleReading(distance, None if point is None else np.array(point, dtype=float), True)
    return DistanceResult({"link_4": reading}, 0.1 if blind else 1.0, blind, stamp)


def test_sensing_problem_names_blind_stale_and_invalid_updates():
    assert sensing_problem(_result(), 1.0, 0.05) is None
    assert sensing_problem(_result(blind=True), 1.0, 0.05).startswith("blind frame")
    assert sensing_problem(_result(stamp=0.9), 1.0, 0.05).startswith("stale frame (age 100 ms)")
    assert sensing_problem(_result(stamp=0.9), 1.0, None) is None
    assert sensing_problem(_result(distance=math.nan), 1.0, 0.05).startswith("invalid reading for link_4")
    assert sensing_problem(_result(point=(math.nan, 0.0, 0.0)), 1.0, 0.05).startswith("invalid reading")


@pytest.mark.parametrize(
    ("spec", "key"),
    [
        ({"kind": "depth_smoke"}, "faults.inject[0].kind"),
        ({"kind": "depth_nan", "start_s": 2.0, "end_s": 1.0}, "faults.inject[0]"),
        ({"kind": "depth_nan", "fraction": 1.5}, "faults.inject[0].fraction"),
        ({"kind": "depth_nan", "colour": 1}, "faults.inject[0].colour"),
    ],
)
def test_bad_fault_specs_name_the_key(spec, key):
    config, _ = load_config(CONFIGS / "case1.toml")
    data = config.model_dump(mode="python")
    data["faults"] = {"inject": [spec]}
    with pytest.raises(ConfigError, match=r"^" + key.replace("[", r"\[").replace("]", r"\]")):
        parse_config(data)


@pytest.mark.slow
@pytest.mark.rendering
def test_depth_mode_faults_on_rendered_frames(robot):
    faults = [
        {"kind": "depth_nan", "start_s": 0.3, "end_s": 0.4},
        {"kind": "depth_zero", "start_s": 0.6, "end_s": 0.7},
        {"kind": "depth_dropout", "start_s": 0.9, "end_s": 1.0, "fraction": 0.9},
        {"kind": "depth_frozen", "start_s": 1.2, "end_s": 1.4},
        {"kind": "depth_delay", "start_s": 1.6, "end_s": 1.8, "delay_s": 0.1},
    ]
    result = run_method(_config(faults, sensing="depth", duration=2.0, methods=["tpik"]), "tpik", robot)
    _check_commands(result, robot)
    for kind in FRAME_KINDS:
        f = result["summary"]["faults"][kind]
        assert f["reaction"] == "safe_stop", (kind, f)
        assert f["reaction_latency_s_max"] <= PERIOD_S + 1e-9
        assert f["moving_steps_while_faulty"] == 0


@pytest.mark.slow
@pytest.mark.rendering
def test_a_fault_of_one_camera_of_two_stops_the_arm(robot):
    config, _ = load_config(CONFIGS / "case1_two_cameras.toml")
    data = config.model_dump(mode="python")
    data["scenario"].update(duration_s=1.2, time_scale=1.0)
    data["methods"] = {"names": ["tpik"], "settings": {}}
    data["faults"] = {
        "inject": [
            {"kind": "depth_nan", "start_s": 0.3, "end_s": 0.5, "camera": 1},
            {"kind": "depth_frozen", "start_s": 0.7, "end_s": 0.9, "camera": 1},
        ]
    }
    result = run_method(parse_config(data), "tpik", robot)
    _check_commands(result, robot)
    for kind in ("depth_nan", "depth_frozen"):
        f = result["summary"]["faults"][kind]
        assert f["reaction"] == "safe_stop", (kind, f)
        assert f["moving_steps_while_faulty"] == 0

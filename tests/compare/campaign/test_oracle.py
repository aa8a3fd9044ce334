"""The clairvoyant oracle witness on hand-built scenarios whose answer is known, its cache and its settings."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from compare.campaign import witness as witness_module
from compare.campaign.witness import cached_witness, run_witness, witness_key
from compare.config import WitnessSpec, parse_config
from compare.sensing.geometric_distance import GeometricDistance
from compare.sensing.person import Person
from compare.sensing.scene import load_workcell
from tests.compare.scenes import CPS, Q0, levels, scene

ORACLE = WitnessSpec.parse("oracle-1s")


def _config(keyframes: list[dict], duration_s: float):
    return scene(keyframes, duration_s, kind="case2")


def _cp(jaco, name: str) -> np.ndarray:
    return np.array(jaco.kinematics(np.array(Q0)).frame_position(name))


def _distance_if_still(config, jaco) -> float:
    """Smallest true distance over the run with the arm held at its start (MuJoCo geometry)."""
    model = load_workcell("jaco2")
    data = mujoco.MjData(model)
    person = Person(model, config.person.keyframes)
    geometry = GeometricDistance(model, rho_m=math.inf)
    kin = jaco.kinematics(np.array(Q0))
    points = {cp: kin.frame_position(cp) for cp in CPS}
    best = math.inf
    for t in np.arange(0.0, config.scenario.sim_time_s, config.scenario.dt):
        person.apply(float(t), data)
        mujoco.mj_kinematics(model, data)
        best = min(best, *geometry.distances(data, points).values())
    return best


def test_oracle_holds_still_when_the_person_stops_short(jaco):
    p7 = _cp(jaco, "link_7")
    frames = [
        {"t": 0.0, "position": [p7[0], p7[1] + 1.6], "yaw": -math.pi / 2},
        {"t": 1.0, "position": [p7[0], p7[1] + 1.05], "yaw": -math.pi / 2},
    ]
    config = _config(frames, 3.0)
    expected = _distance_if_still(config, jaco)
    assert expected > 0.35 + config.oracle.margin_cap_m  # far enough that holding still is optimal
    run = run_witness(config, jaco, ORACLE)
    assert run.entry["held"] is True
    q = run.steps[[f"q_{j}" for j in range(1, 8)]].to_numpy()
    assert np.max(np.abs(q - np.array(Q0))) < 1e-9  # it never moved
    assert run.entry["qp_calls"] == 0
    assert run.entry["min_distance_m"] == pytest.approx(expected, abs=1e-9)


def test_a_witness_holds_only_when_joint_limits_and_walls_held_too(jaco, monkeypatch):
    """The obstacles kept, but a wall passed by more than the metrics' tolerance: not a witness."""
    p7 = _cp(jaco, "link_7")
    frames = [{"t": 0.0, "position": [p7[0], p7[1] + 1.6], "yaw": -math.pi / 2}]
    real = witness_module.compute_summary

    def a_wall_passed(steps, meta):
        summary = real(steps, meta)
        summary["walls"] = {**summary["walls"], "violations": 1, "safety_margin_min": -0.0018}
        return summary

    monkeypatch.setattr(witness_module, "compute_summary", a_wall_passed)
    entry = run_witness(_config(frames, 0.5), jaco, ORACLE).entry
    assert entry["obstacles_margin_min"] > 0.0 and entry["walls_margin_min"] == -0.0018
    assert entry["held"] is False


def test_oracle_retreats_from_a_slow_hand_within_every_limit(jaco):
    p7 = _cp(jaco, "link_7")
    torso = [p7[0], p7[1] + 0.55]
    frames = [
        {"t": 0.0, "position": [p7[0], p7[1] + 1.1], "yaw": -math.pi / 2},
        {"t": 1.0, "position": torso, "yaw": -math.pi / 2, "right_hand": list(p7 + [0.0, 0.45, 0.0])},
        {"t": 4.0, "position": torso, "yaw": -math.pi / 2, "right_hand": list(p7 + [0.0, 0.15, 0.0])},
    ]
    config = _config(frames, 6.0)
    assert _distance_if_still(config, jaco) < 0.3  # holding still would violate: the oracle must act
    run = run_witness(config, jaco, ORACLE)
    e = run.entry
    assert e["held"] is True
    assert e["min_distance_m"] >= 0.35 - 1e-3
    assert e["joint_limits_margin_min"] >= -1e-3 and e["walls_margin_min"] >= -1e-3
    q = run.steps[[f"q_{j}" for j in range(1, 8)]].to_numpy()
    assert np.max(np.abs(q - np.array(Q0))) > 0.05
    assert np.all(np.abs(np.diff(q, axis=0)) <= jaco.v_max * config.scenario.dt * (1 + 1e-6) + 1e-12)


def test_oracle_cannot_escape_a_hand_arriving_in_100_ms(jaco):
    p7 = _cp(jaco, "link_7")
    torso = [p7[0], p7[1] + 0.55]
    arrive_s = 0.1
    frames = [
        {"t": 0.0, "position": torso, "yaw": -math.pi / 2, "right_hand": list(p7 + [0.0, 0.3, 0.35])},
        {"t": arrive_s, "position": torso, "yaw": -math.pi / 2, "right_hand": list(p7)},
    ]
    config = _config(frames, 1.0)
    run = run_witness(config, jaco, ORACLE)
    # Kinematic bound: |ṗ| ≤ Σ_i v_i ‖J_i‖; in 0.1 s link_7 moves at most that far from the hand's centre
    # (20 % for the change of J along the way).
    J = jaco.kinematics(np.array(Q0)).position_jacobian("link_7")
    reach = arrive_s * float(np.linalg.norm(J, axis=0) @ jaco.v_max)
    assert reach < 0.35
    assert run.entry["held"] is False
    assert run.entry["min_distance_m"] <= 1.2 * reach


def test_oracle_is_cached_and_the_key_follows_the_person(jaco, tmp_path):
    p7 = _cp(jaco, "link_7")
    frames = [
        {"t": 0.0, "position": [p7[0], p7[1] + 1.6], "yaw": -math.pi / 2},
        {"t": 0.5, "position": [p7[0], p7[1] + 1.2], "yaw": -math.pi / 2},
    ]
    config = _config(frames, 1.0)
    first = cached_witness(config, jaco, ORACLE, tmp_path)
    again = cached_witness(config, jaco, ORACLE, tmp_path)
    assert first.entry["cached"] is False and again.entry["cached"] is True
    assert {k: v for k, v in again.entry.items() if k != "cached"} == {
        k: v for k, v in first.entry.items() if k != "cached"
    }
    frames[1]["position"] = [p7[0], p7[1] + 1.1]
    assert witness_key(_config(frames, 1.0), jaco, ORACLE) != witness_key(config, jaco, ORACLE)
    assert witness_key(config, jaco, WitnessSpec.parse("oracle-2s")) != witness_key(config, jaco, ORACLE)


def test_oracle_settings_are_checked():
    from compare.config import ConfigError

    with pytest.raises(ConfigError, match="oracle-0.2s"):
        parse_config({"levels": levels(), "oracle": {"witnesses": ["oracle-0.2s"]}})
    with pytest.raises(ConfigError, match="not 'oracle-<T>s' or 'preview-<tau>s'"):
        parse_config({"levels": levels(), "oracle": {"witnesses": ["greedy"]}})
    with pytest.raises(ConfigError, match="knot_s"):
        parse_config({"levels": levels(), "oracle": {"witnesses": ["oracle-0.5s"], "knot_s": 0.6}})
    with pytest.raises(ConfigError, match="listed twice"):
        parse_config({"levels": levels(), "oracle": {"witnesses": ["preview-1s", "preview-1s"]}})
    with pytest.raises(ConfigError, match="avoidable_only needs enabled"):
        parse_config({"levels": levels(), "oracle": {"avoidable_only": True}})
    with pytest.raises(ConfigError, match="unknown QP solver"):
        parse_config({"levels": levels(), "oracle": {"solver": "nope"}})
    with pytest.raises(ConfigError, match="oracle.enabled: the hierarchy has no obstacle_distance task"):
        parse_config({"levels": [levels()[0], levels()[3]], "oracle": {"enabled": True}})

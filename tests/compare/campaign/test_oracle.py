"""The clairvoyant oracle on hand-built scenarios whose answer is known, and its parts."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from compare.campaign.oracle import PersonTrack, cached_oracle, capsule_margins, oracle_key, run_oracle
from compare.config import parse_config
from compare.sensing.geometric_distance import GeometricDistance
from compare.sensing.person import Person, PersonKeyframe
from compare.sensing.scene import load_workcell

Q0 = (4.9, 3.78, 3.392, 1.124, 3.156, 2.03, 0.0)  # case 2's start: EE at (0.10, 0.20, 0.45) m
CPS = ("link_4", "link_6", "link_7")
LEVELS = [
    {"name": "joint_limits", "tasks": [{"type": "joint_limit", "joints": [2, 4, 6], "safety_margin": 0.1}]},
    {
        "name": "walls",
        "tasks": [{"type": "wall_box", "frame": "end_effector", "lower": [-0.5, -0.5, 0.2], "upper": [0.5, 0.5, 0.9]}],
    },
    {
        "name": "obstacles",
        "tasks": [
            {"type": "obstacle_distance", "frames": list(CPS), "safety_distance": 0.35, "physical_distance": 0.1}
        ],
    },
    {"name": "operational", "tasks": [{"type": "position", "frame": "end_effector"}]},
]


def _config(keyframes: list[dict], duration_s: float):
    return parse_config(
        {
            "scenario": {
                "name": "oracle-test",
                "kind": "case2",
                "duration_s": duration_s,
                "sensing": "geometric",
                "simulation": "kinematic",
                "start_q": list(Q0),
            },
            "waypoints": {"positions": []},
            "person": {"keyframes": keyframes},
            "levels": LEVELS,
            "methods": {"names": ["tpik"]},
            "oracle": {"enabled": True},
        }
    )


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
    run = run_oracle(config, jaco)
    assert run.entry["held_safety"] is True
    q = run.steps[[f"q_{j}" for j in range(1, 8)]].to_numpy()
    assert np.max(np.abs(q - np.array(Q0))) < 1e-9  # it never moved
    assert run.entry["qp_calls"] == 0
    assert run.entry["min_distance_m"] == pytest.approx(expected, abs=1e-9)


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
    run = run_oracle(config, jaco)
    e = run.entry
    assert e["held_safety"] is True
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
    run = run_oracle(config, jaco)
    # Kinematic bound: |ṗ| ≤ Σ_i v_i ‖J_i‖; in 0.1 s link_7 moves at most that far from the hand's centre
    # (20 % for the change of J along the way).
    J = jaco.kinematics(np.array(Q0)).position_jacobian("link_7")
    reach = arrive_s * float(np.linalg.norm(J, axis=0) @ jaco.v_max)
    assert reach < 0.35
    assert run.entry["held_safety"] is False
    assert run.entry["min_distance_m"] <= 1.2 * reach


def test_capsule_margins_match_mujoco_geometry():
    model = load_workcell("jaco2")
    data = mujoco.MjData(model)
    frames = [
        PersonKeyframe(0.0, (0.2, 1.2), -1.4),
        PersonKeyframe(1.0, (0.1, 0.7), -1.6, right_hand=(0.1, 0.3, 0.7)),
    ]
    person = Person(model, frames)
    track = PersonTrack.from_person(person, 1.0, 0.01)
    geometry = GeometricDistance(model, rho_m=math.inf)
    rng = np.random.default_rng(3)
    for t in (0.0, 0.37, 1.0):
        person.apply(t, data)
        mujoco.mj_kinematics(model, data)
        points = rng.uniform([-0.6, -0.6, 0.0], [0.6, 1.0, 1.2], (20, 3))
        truth = geometry.distances(data, {str(i): p for i, p in enumerate(points)})
        margin, _ = capsule_margins(points, *track.at(t))
        np.testing.assert_allclose(np.maximum(margin.min(axis=1), 0.0), [truth[str(i)] for i in range(20)], atol=1e-9)


def test_distance_gradient_matches_finite_differences(jaco):
    a = np.array([[0.3, 0.5, 0.2]])
    b = np.array([[0.1, 0.6, 0.9]])
    r = np.array([0.05])
    rng = np.random.default_rng(0)
    for _ in range(5):
        q = np.array(Q0) + rng.uniform(-0.3, 0.3, 7)

        def dist(qq):
            p = jaco.kinematics(qq).frame_position("link_7")[None, :]
            return float(capsule_margins(p, a, b, r)[0][0, 0])

        kin = jaco.kinematics(q)
        _, normal = capsule_margins(kin.frame_position("link_7")[None, :], a, b, r)
        grad = normal[0, 0] @ kin.position_jacobian("link_7")
        h = 1e-6
        fd = np.array([(dist(q + h * e) - dist(q - h * e)) / (2 * h) for e in np.eye(7)])
        np.testing.assert_allclose(grad, fd, atol=1e-6)


def test_oracle_is_cached_and_the_key_follows_the_person(jaco, tmp_path):
    p7 = _cp(jaco, "link_7")
    frames = [
        {"t": 0.0, "position": [p7[0], p7[1] + 1.6], "yaw": -math.pi / 2},
        {"t": 0.5, "position": [p7[0], p7[1] + 1.2], "yaw": -math.pi / 2},
    ]
    config = _config(frames, 1.0)
    first = cached_oracle(config, jaco, tmp_path)
    again = cached_oracle(config, jaco, tmp_path)
    assert first.entry["cached"] is False and again.entry["cached"] is True
    assert {k: v for k, v in again.entry.items() if k != "cached"} == {
        k: v for k, v in first.entry.items() if k != "cached"
    }
    frames[1]["position"] = [p7[0], p7[1] + 1.1]
    assert oracle_key(_config(frames, 1.0), jaco) != oracle_key(config, jaco)


def test_oracle_settings_are_checked():
    from compare.config import ConfigError

    with pytest.raises(ConfigError, match="oracle.horizon_s"):
        parse_config({"levels": LEVELS, "oracle": {"horizon_s": 0.2}})
    with pytest.raises(ConfigError, match="avoidable_only needs enabled"):
        parse_config({"levels": LEVELS, "oracle": {"avoidable_only": True}})
    with pytest.raises(ConfigError, match="unknown QP solver"):
        parse_config({"levels": LEVELS, "oracle": {"solver": "nope"}})
    with pytest.raises(ConfigError, match="oracle.enabled: the hierarchy has no obstacle_distance task"):
        parse_config({"levels": [LEVELS[0], LEVELS[3]], "oracle": {"enabled": True}})

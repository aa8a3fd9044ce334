"""The run's verdict: avoidable with a witness, unavoidable with a proof, undecided otherwise."""

from __future__ import annotations

import math

import numpy as np

from compare.campaign import verdict
from compare.campaign.verdict import run_verdict
from compare.config import parse_config

Q0 = (4.9, 3.78, 3.392, 1.124, 3.156, 2.03, 0.0)
CPS = ("link_4", "link_6", "link_7")
LEVELS = [
    {"name": "joint_limits", "tasks": [{"type": "joint_limit", "joints": [2, 4, 6], "safety_margin": 0.1}]},
    {
        "name": "obstacles",
        "tasks": [
            {"type": "obstacle_distance", "frames": list(CPS), "safety_distance": 0.35, "physical_distance": 0.1}
        ],
    },
    {"name": "operational", "tasks": [{"type": "position", "frame": "end_effector"}]},
]
WITNESSES = ["preview-1s", "preview-0s", "oracle-1s", "oracle-2s"]


def _config(frames: list[dict], duration_s: float, rule: str = "first"):
    return parse_config(
        {
            "scenario": {
                "name": "verdict-test",
                "kind": "scripted",
                "duration_s": duration_s,
                "sensing": "geometric",
                "simulation": "kinematic",
                "start_q": list(Q0),
            },
            "waypoints": {"positions": []},
            "person": {"keyframes": frames},
            "levels": LEVELS,
            "methods": {"names": ["tpik"]},
            "oracle": {"enabled": True, "witnesses": WITNESSES, "witness_rule": rule},
        }
    )


def _approach(jaco, stop: float, duration_s: float, rule: str = "first"):
    """A person walking up to ``stop`` m in front of link_7, hand raised at it."""
    p7 = jaco.kinematics(np.array(Q0)).frame_position("link_7")
    frames = [
        {"t": t, "position": [p7[0], p7[1] + y], "yaw": -math.pi / 2, "right_hand": list(p7 + [0.0, y - 0.45, 0.05])}
        for t, y in ((0.0, 1.6), (1.4, stop))
    ]
    return _config(frames, duration_s, rule)


def _dash(jaco):
    """A hand that starts clear of every threshold and reaches link_7 in 0.1 s."""
    p7 = jaco.kinematics(np.array(Q0)).frame_position("link_7")
    torso = [float(p7[0]), float(p7[1] + 0.75)]
    frames = [
        {"t": 0.0, "position": torso, "yaw": -math.pi / 2, "right_hand": (p7 + [0.0, 0.5, 0.0]).tolist()},
        {"t": 0.1, "position": torso, "yaw": -math.pi / 2, "right_hand": p7.tolist()},
    ]
    return _config(frames, 1.0)


def test_first_rule_stops_at_the_first_witness_that_holds(jaco):
    entry = run_verdict(_approach(jaco, 0.5, 2.5), jaco)
    assert entry["label"] == "avoidable" and entry["held_safety"] is True
    assert list(entry["witnesses"]) == ["preview-1s"] and entry["witness"] == "preview-1s"
    assert entry["certificate"] is None


def test_all_rule_keeps_the_best_witness_and_never_reports_less_than_one_of_them(jaco):
    entry = run_verdict(_approach(jaco, 0.5, 2.5, rule="all"), jaco)
    runs = entry["witnesses"]
    assert list(runs) == WITNESSES
    assert not runs["preview-0s"]["held"]  # a reactive policy fails where looking ahead holds
    best = max(r["min_distance_m"] for r in runs.values())
    assert entry["min_distance_m"] == best
    held = {n: r["min_distance_m"] for n, r in runs.items() if r["held"]}
    assert entry["witness"] == max(held, key=held.get)


def test_a_dash_no_motion_escapes_is_unavoidable_with_its_proof(jaco):
    entry = run_verdict(_dash(jaco), jaco)
    assert entry["label"] == "unavoidable" and entry["held_safety"] is False
    assert list(entry["witnesses"]) == WITNESSES and not any(r["held"] for r in entry["witnesses"].values())
    cert = entry["certificate"]
    assert cert["control_point"] == "link_7" and 0.0 < cert["time_s"] <= 0.1 + 1e-9


def test_no_witness_and_no_proof_is_undecided(jaco, monkeypatch):
    monkeypatch.setattr(verdict, "certify", lambda config, robot: None)
    entry = run_verdict(_dash(jaco), jaco)
    assert entry["label"] == "undecided" and entry["witness"] is None and entry["certificate"] is None
    assert run_verdict(_dash(jaco), jaco, certificate=False)["label"] == "undecided"

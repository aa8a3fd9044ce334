"""The run's verdict: avoidable with a witness, unavoidable with a proof, undecided otherwise."""

from __future__ import annotations

import math

from compare.campaign import verdict
from compare.campaign.verdict import run_verdict
from tests.compare.scenes import control_point, scene

WITNESSES = ["preview-1s", "preview-0s", "oracle-1s", "oracle-2s"]


def _approach(jaco, stop: float, duration_s: float, rule: str = "first"):
    """A person walking up to ``stop`` m in front of link_7, hand raised at it."""
    p7 = control_point(jaco)
    frames = [
        {"t": t, "position": [p7[0], p7[1] + y], "yaw": -math.pi / 2, "right_hand": list(p7 + [0.0, y - 0.45, 0.05])}
        for t, y in ((0.0, 1.6), (1.4, stop))
    ]
    return scene(frames, duration_s, walls=False, oracle={"witnesses": WITNESSES, "witness_rule": rule})


def _dash(jaco):
    """A hand that starts clear of every threshold and reaches link_7 in 0.1 s."""
    p7 = control_point(jaco)
    torso = [float(p7[0]), float(p7[1] + 0.75)]
    frames = [
        {"t": 0.0, "position": torso, "yaw": -math.pi / 2, "right_hand": (p7 + [0.0, 0.5, 0.0]).tolist()},
        {"t": 0.1, "position": torso, "yaw": -math.pi / 2, "right_hand": p7.tolist()},
    ]
    return scene(frames, 1.0, walls=False, oracle={"witnesses": WITNESSES})


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

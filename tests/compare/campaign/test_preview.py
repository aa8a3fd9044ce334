"""The greedy preview witness: still when nothing threatens, away from where the person will be, within every limit."""

from __future__ import annotations

import math

import numpy as np

from compare.campaign.witness import run_witness
from compare.config import WitnessSpec
from tests.compare.scenes import Q0, control_point, scene


def _q(run) -> np.ndarray:
    return run.steps[[f"q_{j}" for j in range(1, 8)]].to_numpy()


def test_preview_holds_still_while_the_person_stays_far(jaco):
    p7 = control_point(jaco)
    frames = [
        {"t": 0.0, "position": [p7[0], p7[1] + 1.6], "yaw": -math.pi / 2},
        {"t": 1.0, "position": [p7[0], p7[1] + 1.4], "yaw": -math.pi / 2},
    ]
    run = run_witness(scene(frames, 2.0), jaco, WitnessSpec.parse("preview-1s"))
    assert run.entry["held"] is True
    assert np.max(np.abs(_q(run) - np.array(Q0))) < 1e-6


def test_preview_leaves_before_the_person_arrives_and_keeps_every_limit(jaco):
    """A person walking up at 0.8 m/s, hand raised at link_7: looking 1 s ahead starts the retreat early
    enough; looking 0 s ahead (purely reactive) does not.

    On the dynamic plant (decoupled drive), judged by the methods' metrics: obstacle, joint-limit and
    wall safety thresholds all held.
    """
    p7 = control_point(jaco)
    arrive = (1.6 - 0.5) / 0.8
    frames = [
        {"t": t, "position": [p7[0], p7[1] + y], "yaw": -math.pi / 2, "right_hand": list(p7 + [0.0, y - 0.45, 0.05])}
        for t, y in ((0.0, 1.6), (arrive, 0.5), (arrive + 1.5, 0.5))
    ]
    config = scene(frames, arrive + 1.5, simulation="dynamic")
    ahead = run_witness(config, jaco, WitnessSpec.parse("preview-1s"))
    now = run_witness(config, jaco, WitnessSpec.parse("preview-0s"))
    e = ahead.entry
    assert e["held"] is True, e
    assert e["min_distance_m"] >= 0.35 - 1e-3
    assert e["joint_limits_margin_min"] >= -1e-3 and e["walls_margin_min"] >= -1e-3
    assert now.entry["held"] is False and now.entry["min_distance_m"] < e["min_distance_m"] - 0.1
    qdot = ahead.steps[[f"qdot_{j}" for j in range(1, 8)]].to_numpy()
    assert np.all(np.abs(qdot) <= jaco.v_max + 1e-12)
    assert np.max(np.abs(qdot)) > 0.3  # it did move

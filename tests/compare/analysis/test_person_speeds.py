"""The realized person's speeds: per body part in a run, their distribution over a sweep."""

from __future__ import annotations

import math

import numpy as np
import pytest

from compare.analysis.person_speeds import report_lines, sweep_person_speeds
from compare.sensing.person import Person, PersonKeyframe
from compare.sensing.person_track import PersonTrack, max_speeds_by_part
from compare.sensing.scene import load_workcell


def test_a_walking_person_moves_every_part_at_the_walking_speed_and_a_reaching_hand_faster():
    model = load_workcell("jaco2")
    frames = [
        PersonKeyframe(0.0, (0.0, 1.6), -math.pi / 2),
        PersonKeyframe(1.0, (0.0, 0.8), -math.pi / 2),  # 0.8 m/s, arms hanging
        PersonKeyframe(1.5, (0.0, 0.8), -math.pi / 2, right_hand=(0.0, 0.5, 0.6)),
    ]
    speeds = max_speeds_by_part(PersonTrack.from_person(Person(model, frames), 1.5, 0.01))
    assert set(speeds) == {"torso", "upper_arm", "forearm", "hand"}
    assert speeds["torso"] == pytest.approx(0.8, rel=1e-6)
    assert speeds["hand"] > speeds["torso"] + 0.1


def test_sweep_distribution_and_report():
    runs = [{"person": {"max_speed_mps": {"torso": v, "hand": 2 * v}}} for v in np.linspace(0.5, 1.5, 11)]
    runs.append({"methods": {}})  # a run without the entry counts for nothing
    out = sweep_person_speeds(runs)
    assert out["torso"] == {"median": 1.0, "p95": pytest.approx(1.45), "max": 1.5, "runs": 11}
    assert out["hand"]["max"] == 3.0
    text = "\n".join(report_lines({"person": {"max_speed_mps": out}}))
    assert "| torso | 11 | 1.00 | 1.45 | 1.50 |" in text
    assert sweep_person_speeds([{}]) is None and report_lines({}) == []

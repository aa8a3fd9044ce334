"""Violation episodes and the person's closing speed (compare.analysis.violations)."""

from __future__ import annotations

import numpy as np
import pytest

from compare.analysis.violations import _episodes, closing_speed
from compare.sensing.person import Person, PersonKeyframe
from compare.sensing.person_track import PersonTrack
from compare.sensing.scene import load_workcell


def test_episodes_are_the_runs_past_the_tolerance():
    margin = np.array([0.1, -0.0005, -0.01, -0.02, 0.0, -0.003, np.nan, -0.5])
    assert _episodes(margin) == [(2, 4), (5, 6), (7, 8)]


def test_closing_speed_of_a_person_walking_straight_at_a_point():
    frames = [PersonKeyframe(0.0, (0.0, 2.0), -np.pi / 2), PersonKeyframe(3.0, (0.0, 0.5), -np.pi / 2)]
    track = PersonTrack.from_person(Person(load_workcell("jaco2"), frames), 3.0, 0.01)
    point = np.array([0.0, -0.3, 0.4])  # in front of the torso, at chest height
    assert closing_speed(track, point, 1.5) == pytest.approx(0.5, abs=0.01)
    assert closing_speed(track, point, 3.5) == pytest.approx(0.0, abs=1e-9)  # standing still

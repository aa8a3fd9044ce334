"""The ground truth of a run: the steps it keeps, computed at the end, are the per-step numbers bit for bit."""

from __future__ import annotations

import math

import mujoco
import numpy as np

from compare.sensing.ground_truth import GroundTruth
from compare.sensing.person import Person, PersonKeyframe
from compare.sensing.scene import load_workcell
from tests.conftest import random_configuration

FRAMES = ("link_4", "link_6", "link_7", "end_effector")


def test_recorded_steps_are_the_per_step_distances_bit_for_bit(jaco):
    """The person walks up and reaches; the arm at random poses; step 3 is not recorded (NaN)."""
    model = load_workcell("jaco2")
    data = mujoco.MjData(model)
    person = Person(
        model,
        [
            PersonKeyframe(0.0, (0.2, 1.2), -1.4),
            PersonKeyframe(1.0, (0.1, 0.5), -1.6, right_hand=(0.1, 0.2, 0.6)),
        ],
    )
    truth = GroundTruth(model, data, FRAMES)
    steps = 40
    truth.start(steps)
    rng = np.random.default_rng(5)
    want = np.full((steps, len(FRAMES)), np.nan)
    want_points = np.full((steps, len(FRAMES), 3), np.nan)
    for i in range(steps):
        person.apply(i / (steps - 1), data)
        mujoco.mj_kinematics(model, data)
        kin = jaco.kinematics(random_configuration(jaco, rng))
        now = truth(kin)
        if i != 3:
            truth.record(i, kin)
            want[i] = [now[f] for f in FRAMES]
            kin.frame_positions(FRAMES, want_points[i])
    got = truth.recorded(steps)
    points = truth.recorded_points(steps + 2)  # the control points kept, NaN where none was (and past the run)
    assert np.array_equal(points[:steps].view(np.int64), want_points.view(np.int64))
    assert np.isnan(points[steps:]).all()
    assert set(got) == set(FRAMES)
    table = np.column_stack([got[f] for f in FRAMES])
    assert np.array_equal(table.view(np.int64), want.view(np.int64))  # bit for bit, NaN rows included
    assert np.all(np.isnan(table[3])) and np.isfinite(np.delete(table, 3, axis=0)).all()
    assert (table[np.isfinite(table)] < math.inf).all() and (np.nanmin(table) < 0.5)


def test_a_truth_without_frames_records_nothing(jaco):
    model = load_workcell("jaco2")
    truth = GroundTruth(model, mujoco.MjData(model), ())
    truth.start(2)
    kin = jaco.kinematics(jaco.home)
    truth.record(0, kin)
    assert truth(kin) == {} and truth.recorded(2) == {}

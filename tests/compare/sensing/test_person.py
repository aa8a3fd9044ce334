"""The capsule person: keyframe interpolation, arm IK, mocap bodies in the work-cell scene."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from compare.config import PersonKeyframe as ConfigKeyframe
from compare.sensing import Person, PersonKeyframe, SensingError, load_workcell, make_data
from compare.sensing.person import REACH_FRACTION

YAW = -math.pi / 2  # facing the arm from +y


@pytest.fixture(scope="module")
def model():
    return load_workcell()


def _mujoco_capsule(model, data, name):
    g = model.geom(name).id
    centre = data.geom_xpos[g]
    axis = data.geom_xmat[g].reshape(3, 3)[:, 2]
    half = model.geom_size[g][1] if model.geom_type[g] == mujoco.mjtGeom.mjGEOM_CAPSULE else 0.0
    return centre - half * axis, centre + half * axis


def test_home_keyframe_still_resets_and_the_scene_steps_cleanly_with_a_moving_person(jaco, model):
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, model.keyframe("home").id)
    assert model.nq == jaco.nq  # mocap bodies add no qpos
    person = Person(
        model,
        [PersonKeyframe(0.0, (0.0, 1.35), YAW), PersonKeyframe(0.5, (0.05, 0.95), YAW, right_hand=(0.0, 0.6, 0.7))],
    )
    for _ in range(500):
        person.apply(data.time, data)
        mujoco.mj_step(model, data)
    assert np.all(data.warning.number == 0)
    assert np.allclose(data.qpos[: jaco.nq], jaco.home, atol=2e-3)


def test_torso_and_yaw_interpolate_linearly_along_the_shorter_arc(model):
    person = Person(model, [PersonKeyframe(0.0, (0.0, 1.0), 3.0), PersonKeyframe(2.0, (1.0, 2.0), -3.0)])
    pose = person.pose_at(1.0)
    assert pose.position == pytest.approx((0.5, 1.5))
    # 3.0 -> -3.0 rad the short way passes through pi, not through 0
    assert math.cos(pose.yaw) == pytest.approx(-1.0, abs=1e-12)
    assert person.pose_at(-5.0).position == pytest.approx((0.0, 1.0))
    assert person.pose_at(10.0).position == pytest.approx((1.0, 2.0))


def test_hand_rises_from_hanging_to_its_target(model):
    target = np.array([0.0, 0.6, 0.7])
    person = Person(
        model, [PersonKeyframe(0.0, (0.0, 1.0), YAW), PersonKeyframe(1.0, (0.0, 1.0), YAW, right_hand=target)]
    )
    hanging = Person(model, [PersonKeyframe(0.0, (0.0, 1.0), YAW)]).pose_at(0.0).hands["r"]  # no target: hangs
    np.testing.assert_allclose(person.pose_at(0.5).hands["r"], (hanging + target) / 2)
    assert hanging[2] < 0.2  # by the hip


def test_reachable_target_is_reached_and_segment_lengths_are_kept(model):
    person = Person(
        model, [PersonKeyframe(0.0, (0.1, 0.9), YAW, right_hand=(0.0, 0.55, 0.75), left_hand=(0.3, 0.6, 0.5))]
    )
    caps = person.capsules_at(0.0)
    for side, target in (("r", (0.0, 0.55, 0.75)), ("l", (0.3, 0.6, 0.5))):
        upper_a, upper_b, _ = caps[f"person_{side}_upperarm"]
        fore_a, fore_b, _ = caps[f"person_{side}_forearm"]
        hand_a, hand_b, _ = caps[f"person_{side}_hand"]
        np.testing.assert_allclose((hand_a + hand_b) / 2, target, atol=1e-9)
        np.testing.assert_allclose(upper_b, fore_a, atol=1e-12)  # elbow
        np.testing.assert_allclose(fore_b, hand_a, atol=1e-12)  # wrist
        for name, (a, b) in {
            "upperarm": (upper_a, upper_b),
            "forearm": (fore_a, fore_b),
            "hand": (hand_a, hand_b),
        }.items():
            g = model.geom(f"person_{side}_{name}").id
            assert np.linalg.norm(b - a) == pytest.approx(2 * model.geom_size[g][1])


def test_unreachable_target_is_approached_on_its_line_with_the_elbow_still_bent(model):
    far = np.array([-1.0, -1.0, 0.6])
    person = Person(model, [PersonKeyframe(0.0, (0.0, 1.0), YAW, right_hand=tuple(far))])
    caps = person.capsules_at(0.0)
    shoulder, elbow, _ = caps["person_r_upperarm"]
    direction = (far - shoulder) / np.linalg.norm(far - shoulder)
    hand_a, hand_b, _ = caps["person_r_hand"]
    centre = (hand_a + hand_b) / 2
    l1 = np.linalg.norm(elbow - shoulder)
    l2 = np.linalg.norm(centre - elbow)
    np.testing.assert_allclose(centre - shoulder, REACH_FRACTION * (l1 + l2) * direction, atol=1e-9)
    off_line = (elbow - shoulder) - ((elbow - shoulder) @ direction) * direction
    assert np.linalg.norm(off_line) > 0.05  # bent: the elbow is off the shoulder-hand line


def test_elbow_speed_stays_bounded_when_a_target_comes_into_reach(model):
    """Near full stretch the two-link elbow moves ever faster per metre of the hand (h' → ∞): capped reach."""
    shoulder = Person(model, [PersonKeyframe(0.0, (0.0, 1.0), YAW)]).capsules_at(0.0)["person_r_upperarm"][0]
    out = np.array([0.0, -1.0, 0.0])  # straight ahead of the person (facing -y)
    frames = [
        PersonKeyframe(0.0, (0.0, 1.0), YAW, right_hand=tuple(shoulder + 0.8 * out)),
        PersonKeyframe(1.0, (0.0, 1.0), YAW, right_hand=tuple(shoulder + 0.3 * out)),
    ]
    caps = Person(model, frames).capsule_ends(np.linspace(0.0, 1.0, 2001))
    hand_speed = 0.5  # m/s of the target
    speeds = np.linalg.norm(np.diff(caps.b, axis=0), axis=2) / (1.0 / 2000)
    elbow = caps.names.index("person_r_upperarm")
    assert speeds[:, elbow].max() < 1.5 * hand_speed


def test_poses_on_the_sampling_grid_equal_poses_computed_one_at_a_time(model):
    frames = [PersonKeyframe(0.0, (0.3, 1.2), 2.0), PersonKeyframe(4.0, (-0.2, 0.8), -2.5, right_hand=(0.1, 0.4, 0.6))]
    gridded = Person(model, frames, sample_period_s=0.01)
    direct = Person(model, frames)
    a, b = make_data(model), make_data(model)
    for k in (0, 1, 255, 256, 257, 399, 600):
        gridded.apply(k * 0.01, a)
        direct.apply(k * 0.01, b)
        np.testing.assert_array_equal(a.mocap_pos, b.mocap_pos)
        np.testing.assert_array_equal(a.mocap_quat, b.mocap_quat)
    gridded.apply(1.234567, a)  # off the grid: computed alone
    direct.apply(1.234567, b)
    np.testing.assert_array_equal(a.mocap_pos, b.mocap_pos)


def test_mocap_bodies_carry_the_capsules_of_the_keyframes(model):
    data = make_data(model)
    person = Person(
        model,
        [PersonKeyframe(0.0, (0.3, 1.2), 2.0), PersonKeyframe(4.0, (-0.2, 0.8), -2.5, right_hand=(0.1, 0.4, 0.6))],
    )
    for t in (0.0, 1.3, 2.9, 4.0):
        person.apply(t, data)
        mujoco.mj_kinematics(model, data)
        for name, (a, b, radius) in person.capsules_at(t).items():
            ma, mb = _mujoco_capsule(model, data, name)
            assert (
                min(np.linalg.norm(ma - a) + np.linalg.norm(mb - b), np.linalg.norm(ma - b) + np.linalg.norm(mb - a))
                < 1e-9
            )
            assert model.geom_size[model.geom(name).id][0] == pytest.approx(radius)


def test_person_stands_on_the_floor_and_is_about_1_75_m_tall(model):
    data = make_data(model)
    Person(model, [PersonKeyframe(0.0, (0.0, 1.2), YAW)]).apply(0.0, data)
    mujoco.mj_kinematics(model, data)
    ids = np.flatnonzero(model.geom_group == 1)
    tops = data.geom_xpos[ids, 2] + model.geom_rbound[ids]
    bottoms = [
        min(_mujoco_capsule(model, data, model.geom(int(g)).name), key=lambda p: p[2])[2] - model.geom_size[g][0]
        for g in ids
    ]
    assert min(bottoms) == pytest.approx(-0.75, abs=0.01)
    assert max(tops) - min(bottoms) == pytest.approx(1.75, abs=0.05)


def test_no_keyframes_parks_the_person_out_of_range(model):
    data = make_data(model)
    person = Person(model)
    assert not person.present
    person.apply(12.0, data)
    mujoco.mj_kinematics(model, data)
    ids = np.flatnonzero(model.geom_group == 1)
    assert np.all(np.linalg.norm(data.geom_xpos[ids], axis=1) > 20.0)


def test_standing_still_rewrites_nothing_but_a_reset_is_noticed(model):
    data = make_data(model)
    person = Person(model, [PersonKeyframe(0.0, (0.0, 1.0), YAW), PersonKeyframe(5.0, (0.0, 1.0), YAW)])
    person.apply(1.0, data)
    before = data.mocap_pos.copy()
    person.apply(2.0, data)
    np.testing.assert_array_equal(data.mocap_pos, before)
    mujoco.mj_resetData(model, data)  # mocap back to the model's parked pose
    person.apply(3.0, data)
    np.testing.assert_array_equal(data.mocap_pos, before)


def test_config_keyframes_and_time_scale_are_accepted(model):
    frames = [
        ConfigKeyframe(t=0.0, position=(0.0, 1.0)),
        ConfigKeyframe(t=10.0, position=(1.0, 1.0), right_hand=(0, 0.5, 0.6)),
    ]
    person = Person(model, frames, time_scale=0.5)
    assert person.times == [0.0, 5.0]
    assert person.pose_at(2.5).position == pytest.approx((0.5, 1.0))


@pytest.mark.parametrize(
    ("frames", "match"),
    [
        ([PersonKeyframe(1.0, (0, 0)), PersonKeyframe(1.0, (1, 0))], "increase"),
        ([PersonKeyframe(0.0, (math.nan, 0))], "finite"),
        ([PersonKeyframe(0.0, (0, 0), right_hand=(0, 0))], "3 finite"),
    ],
)
def test_bad_keyframes_are_rejected_with_a_clear_error(model, frames, match):
    with pytest.raises(SensingError, match=match):
        Person(model, frames)

"""The work cell of every arm: compiled, driven, and seen by the depth camera only where the self-filter removes it.

References: MuJoCo's compiled model and its own mesh vertices (the proxies must contain them),
MuJoCo stepping (no warnings, home held by the velocity servos), and the rendered depth image
(after background and self-filter, an arm alone leaves no pixel; a hand next to it is measured
as the geometry says).
"""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

import robots
from compare.config import PersonKeyframe
from compare.sensing import DepthPipeline, GeometricDistance, Person, control_point_positions, make_data
from compare.sensing.scene import arm_qpos_addresses, set_arm_configuration
from robots.workcell import COLLISION_GROUP, VISUAL_GROUP
from tests.conftest import random_configuration

ARMS = ("jaco2", "panda", "ur5")
COMPOSED = ("panda", "ur5")  # attached to robots/workcell/workcell.xml (the Jaco² has its own file)


@pytest.fixture(scope="module", params=ARMS)
def cell(request) -> tuple[robots.Robot, mujoco.MjModel]:
    arm = robots.load(request.param)
    return arm, arm.workcell_model()


def test_arm_joints_come_first_with_velocity_servos_at_the_velocity_limits(cell):
    arm, model = cell
    np.testing.assert_array_equal(arm_qpos_addresses(model), np.arange(arm.nq))
    assert [model.joint(j).name for j in range(arm.nq)] == list(arm.joint_names)
    assert model.nu >= arm.nq
    np.testing.assert_allclose(model.actuator_ctrlrange[: arm.nq, 1], arm.v_max)
    np.testing.assert_allclose(model.actuator_ctrlrange[: arm.nq, 0], -arm.v_max)
    # velocity servos: force = kv (ctrl - qdot)
    np.testing.assert_allclose(model.actuator_biasprm[: arm.nq, 2], -model.actuator_gainprm[: arm.nq, 0])
    np.testing.assert_array_equal(model.actuator_trnid[: arm.nq, 0], np.arange(arm.nq))
    np.testing.assert_allclose(model.key_qpos[model.keyframe("home").id][: arm.nq], arm.home)
    assert model.camera("depth_camera").id >= 0


def test_scene_steps_without_warnings_and_the_servos_hold_home(cell):
    arm, model = cell
    data = make_data(model)
    for _ in range(500):
        mujoco.mj_step(model, data)
    assert np.all(data.warning.number == 0)
    np.testing.assert_allclose(data.qpos[: arm.nq], arm.home, atol=5e-3)


@pytest.mark.parametrize("name", COMPOSED)
def test_every_mesh_is_inside_its_primitive_proxy(name):
    arm = robots.load(name)
    model = arm.workcell_model()
    data = make_data(model)
    rng = np.random.default_rng(4)
    set_arm_configuration(model, data, random_configuration(arm, rng))
    mujoco.mj_kinematics(model, data)
    meshes = [g for g in range(model.ngeom) if model.geom_type[g] == mujoco.mjtGeom.mjGEOM_MESH]
    assert meshes, "the URDF's collision meshes are in the cell"
    for g in meshes:
        assert model.geom_group[g] == COLLISION_GROUP and model.geom_contype[g] == 0
        proxy = model.geom(model.geom(g).name + "_proxy").id
        assert model.geom_group[proxy] == VISUAL_GROUP and model.geom_bodyid[proxy] == model.geom_bodyid[g]
        mesh = model.geom_dataid[g]
        start, count = model.mesh_vertadr[mesh], model.mesh_vertnum[mesh]
        local = model.mesh_vert[start : start + count].astype(float)
        world = data.geom_xpos[g] + local @ data.geom_xmat[g].reshape(3, 3).T
        # the vertices in the proxy's frame, from MuJoCo's pose of the proxy
        p = (world - data.geom_xpos[proxy]) @ data.geom_xmat[proxy].reshape(3, 3)
        size = model.geom_size[proxy]
        if model.geom_type[proxy] == mujoco.mjtGeom.mjGEOM_BOX:
            assert np.all(np.abs(p) <= size + 1e-9)
        else:
            assert model.geom_type[proxy] == mujoco.mjtGeom.mjGEOM_CAPSULE
            axial = np.clip(p[:, 2], -size[1], size[1])
            assert np.all(np.linalg.norm(p - np.c_[np.zeros((count, 2)), axial], axis=1) <= size[0] + 1e-9)


@pytest.mark.parametrize("name", COMPOSED)
def test_no_arm_geom_collides_and_the_camera_sees_only_primitives(name):
    arm = robots.load(name)
    model = arm.workcell_model()
    arm_geoms = np.flatnonzero(model.body_rootid[model.geom_bodyid] == model.body(arm.base_body).id)
    assert np.all(model.geom_contype[arm_geoms] == 0) and np.all(model.geom_conaffinity[arm_geoms] == 0)
    seen = arm_geoms[model.geom_group[arm_geoms] == VISUAL_GROUP]
    assert seen.size and not np.any(model.geom_type[seen] == mujoco.mjtGeom.mjGEOM_MESH)


@pytest.mark.rendering
@pytest.mark.parametrize("name", ARMS)
def test_the_self_filter_leaves_no_arm_pixel_and_keeps_a_hand_beside_it(name):
    arm = robots.load(name)
    model = arm.workcell_model()
    pipeline = DepthPipeline(model)
    rng = np.random.default_rng(5)
    try:
        for _ in range(3):  # the arm alone, at random poses: nothing is left for the distance
            data = make_data(model, random_configuration(arm, rng, inset=0.3))
            raw = pipeline.render(data)
            assert np.count_nonzero(raw.depth_m > 0) > 0
            filtered = pipeline.filter(raw, data=data)
            assert np.count_nonzero(filtered.depth_m > 0) == 0
        # A hand 0.15 m beside the last control point, in view: measured like the geometry says.
        data = make_data(model)
        points = control_point_positions(arm.kinematics(data.qpos[: arm.nq]), arm.control_points)
        hand = points[arm.control_points[-1]] + np.array([0.0, 0.15, 0.0])
        person = Person(model, [PersonKeyframe(t=0.0, position=(0.0, 0.8), yaw=-math.pi / 2, right_hand=tuple(hand))])
        person.apply(0.0, data)
        mujoco.mj_forward(model, data)
        depth = pipeline.sense(data, points)
        truth = GeometricDistance(model, rho_m=math.inf).distances(data, points)
        cp = arm.control_points[-1]
        assert depth.readings[cp].in_range
        # The hand survives the filter and is measured near the truth: the depth-space distance sees
        # only the camera's side of the capsules (a hidden closest point reads a few mm farther).
        assert abs(depth.readings[cp].distance_m - truth[cp]) < 0.02
    finally:
        pipeline.close()


def test_each_caller_gets_its_own_copy_of_the_compiled_work_cell(cell):
    """Compiled once per robot, copied per call: an edit of one model changes no other, and a copy
    is the compile (same sizes, same geometry)."""
    from robots.workcell import workcell_model

    arm, model = cell
    mine, fresh = arm.workcell_model(), workcell_model(arm)
    assert mine is not model and (mine.nbody, mine.ngeom, mine.nq) == (fresh.nbody, fresh.ngeom, fresh.nq)
    np.testing.assert_array_equal(mine.geom_size, fresh.geom_size)
    np.testing.assert_array_equal(mine.body_pos, fresh.body_pos)
    before = model.geom_size.copy()
    mine.geom_size[:] = 9.0
    np.testing.assert_array_equal(model.geom_size, before)
    np.testing.assert_array_equal(arm.workcell_model().geom_size, fresh.geom_size)

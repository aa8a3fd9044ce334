"""``mink-posture``: ``mink`` with the regularisation of mink's arm examples (posture task, lm_damping, damping)."""

from __future__ import annotations

import mink
import numpy as np
import pytest
import qpsolvers

from compare.methods import make_method
from qp_baseline.mink_peer import POSTURE_PRESET, MinkSolver
from tests.qp_baseline.helpers import DT, joint_limit_level, obstacle_level, position_level, wall_box_level
from tpik.hierarchy import Hierarchy
from tpik.tasks import ObstacleDistanceTask


def test_the_preset_is_the_examples_values_and_the_config_overrides_it_key_by_key(jaco):
    solver = make_method("mink-posture", jaco)
    assert isinstance(solver, MinkSolver) and solver.formulation == "soft_return"
    s = solver.settings
    assert (s.posture_cost, s.lm_damping, s.damping, s.level_cost_ratio) == (1e-2, 1.0, 1e-3, 10.0)
    tuned = make_method("mink-posture", jaco, {"posture_cost": 0.1, "level_cost_ratio": 3.0}).settings
    assert (tuned.posture_cost, tuned.level_cost_ratio, tuned.lm_damping, tuned.damping) == (0.1, 3.0, 1.0, 1e-3)
    plain = make_method("mink", jaco).settings
    assert (plain.posture_cost, plain.lm_damping, plain.damping) == (0.0, 0.0, 1e-12)


def test_velocity_is_what_mink_solve_ik_returns_for_the_examples_setup(jaco):
    """FrameTask with lm_damping, PostureTask at the start posture, damping 1e-3: as mink's Panda example.

    Both tasks take the per-step gain the EE task's reference gives (2 /s × dt): in the example both
    have gain 1, each asking its whole error in one step, so they keep the example's ratio.
    """
    q0 = jaco.home
    kin = jaco.kinematics(q0)
    target = kin.frame_position("end_effector") + np.array([0.02, -0.01, 0.03])
    ours = make_method("mink-posture", jaco).solve(Hierarchy([position_level(target, gain=2.0)]), kin, DT)

    configuration = mink.Configuration(jaco.mj_model, q0)
    body = "j2s7s300_end_effector"
    frame = mink.FrameTask(body, "body", position_cost=1.0, orientation_cost=0.0, gain=2.0 * DT, lm_damping=1.0)
    pose = configuration.get_transform_frame_to_world(body, "body").as_matrix()
    pose[:3, 3] = target
    frame.set_target(mink.SE3.from_matrix(pose))
    posture = mink.PostureTask(jaco.mj_model, cost=1e-2, gain=2.0 * DT)
    posture.set_target(q0)
    velocities = {name: float(v) for name, v in zip(jaco.joint_names, jaco.v_max, strict=True)}
    limits = [mink.ConfigurationLimit(jaco.mj_model), mink.VelocityLimit(jaco.mj_model, velocities)]
    theirs = mink.solve_ik(configuration, [frame, posture], DT, "daqp", damping=1e-3, limits=limits)
    np.testing.assert_allclose(ours.qdot, theirs, atol=1e-9)


def test_the_posture_task_pulls_the_null_space_back_to_the_start_posture(jaco):
    """Moved 0.2 rad along the EE's null space with the EE on target: mink-posture heads back, mink stays."""
    q0 = jaco.home.copy()
    ee_jacobian = jaco.kinematics(q0).position_jacobian("end_effector")
    null = np.linalg.svd(ee_jacobian)[2][-1]  # a unit vector the EE position does not see (first order)
    q1 = q0 + 0.2 * null
    steps = {}
    for name in ("mink-posture", "mink"):
        solver = make_method(name, jaco)
        level = position_level(jaco.kinematics(q0).frame_position("end_effector"))
        task = level.tasks[0]
        hierarchy = Hierarchy([joint_limit_level(jaco), level])
        solver.solve(hierarchy, jaco.kinematics(q0), DT)  # the start posture
        task.set_target(jaco.kinematics(q1).frame_position("end_effector"))  # the EE is where it should be
        steps[name] = solver.solve(hierarchy, jaco.kinematics(q1), DT).qdot
        if name == "mink-posture":
            np.testing.assert_array_equal(solver.posture_target, q0)
    back = float(-null @ steps["mink-posture"])  # rad/s toward q0 along the null direction
    cost, damping = POSTURE_PRESET["posture_cost"], POSTURE_PRESET["damping"]
    # The posture task asks the EE task's gain (1 /s) times 0.2 rad, weighted cost² against the damping.
    assert back == pytest.approx(1.0 * 0.2 * cost**2 / (cost**2 + damping), rel=0.05)
    ee_speed = np.linalg.norm(jaco.kinematics(q1).position_jacobian("end_effector") @ steps["mink-posture"])
    assert ee_speed < 0.05 * back  # the EE barely moves: the pull is in the null space
    assert abs(float(null @ steps["mink"])) < 1e-6  # mink alone has nothing pulling it back


def _case2_like(jaco, q: np.ndarray, rng: np.random.Generator) -> Hierarchy:
    """Joint limits, walls, obstacles within reach of two control points (some past the threshold), EE 2 cm off."""
    kin = jaco.kinematics(q)
    obstacles = obstacle_level(gain=2.0)
    for task in obstacles.tasks:
        assert isinstance(task, ObstacleDistanceTask)
        direction = rng.normal(size=3)
        task.set_obstacle(
            kin.frame_position(task.frame) + rng.uniform(0.3, 0.45) * direction / np.linalg.norm(direction)
        )
    target = kin.frame_position("end_effector") + rng.uniform(-0.02, 0.02, size=3)
    return Hierarchy([joint_limit_level(jaco, gain=2.0), wall_box_level(gain=2.0), obstacles, position_level(target)])


@pytest.mark.parametrize("seed", range(4))
def test_the_hessian_is_well_conditioned(jaco, monkeypatch, seed):
    """Every eigenvalue of mink-posture's H is at least damping + posture_cost²; mink's reach 1e-12."""
    rng = np.random.default_rng(seed)
    model = jaco.mj_model
    lo = np.where(model.jnt_limited, model.jnt_range[:, 0] + 0.05, -np.inf)
    hi = np.where(model.jnt_limited, model.jnt_range[:, 1] - 0.05, np.inf)
    q = np.clip(jaco.home + rng.uniform(-0.3, 0.3, size=jaco.nq), lo, hi)  # inside the model's ranges
    posed: list[qpsolvers.Problem] = []
    real = qpsolvers.solve_problem

    def spy(problem: qpsolvers.Problem, **kwargs):  # type: ignore[no-untyped-def]
        posed.append(problem)
        return real(problem, **kwargs)

    monkeypatch.setattr(qpsolvers, "solve_problem", spy)
    smallest = {}
    for name in ("mink-posture", "mink"):
        hierarchy = _case2_like(jaco, q, np.random.default_rng(seed))
        result = make_method(name, jaco).solve(hierarchy, jaco.kinematics(q), DT)
        assert result.status.value != "failed"
        smallest[name] = float(np.linalg.eigvalsh(posed[-1].P)[0])
    floor = POSTURE_PRESET["damping"] + POSTURE_PRESET["posture_cost"] ** 2
    assert smallest["mink-posture"] >= floor * (1 - 1e-9)
    assert smallest["mink"] < 1e-9  # the EE task leaves a null space only the 1e-12 damping fills

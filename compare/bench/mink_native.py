r"""``mink-native``: the paper's case-2 problem written with mink's API alone.

The reference of every "× mink" ratio of ``tpik-compare bench`` (docs/design.md §7). No project class is
involved in a step: no task objects, no hierarchy, no pinocchio; only mink's ``Configuration``,
a ``FrameTask`` for the EE position, ``ConfigurationLimit`` and ``VelocityLimit``, one custom
``Limit`` for the safety thresholds (joint limits 2, 4, 6, six EE walls, the obstacle distance of
three control points), one custom ``Task`` that brings a quantity past its safety threshold back,
and ``mink.solve_ik`` with DAQP. Its formulation is the project's ``mink`` peer's
(:mod:`qp_baseline.mink_peer`): limits that Δq = 0 satisfies (inside its safe set a quantity
may approach its threshold at most at :math:`K(\sigma - \sigma_s)`, past it no further), the
soft return weighted ρ = 10 per level above the EE task. ``tests/compare/bench/test_mink_native.py``
checks that both give the same step.

A step (:meth:`MinkCase2.step`): ``configuration.update(q)``, evaluate the 12 safety quantities
from ``configuration.data`` (MuJoCo kinematics and ``mj_jacBody``) and set the EE target (the
row updates), then what ``mink.solve_ik`` does — its limit check and ``mink.build_ik`` (the
problem build), ``qpsolvers.solve_problem`` with DAQP (the solver), Δq / dt — with the three
parts timed apart (:attr:`MinkCase2.parts_s`).
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence

import mink
import mujoco
import numpy as np
import qpsolvers


class _SafetyRows:
    r"""σ, J and the reference rates of every safety quantity, computed once per step from mink's data.

    Quantities (each :math:`\sigma \ge \sigma_s`, i.e. one-sided): for joint j,
    :math:`q_{max} - m - q_j` and :math:`q_j - q_{min} - m`; for a wall, :math:`n^Tp - d`; for a
    control point, :math:`\|O - P\|` with the paper's partial Jacobian.
    """

    def __init__(
        self,
        model: mujoco.MjModel,
        joints: Sequence[tuple[str, float, float]],
        ee_body: str,
        walls: Sequence[tuple[np.ndarray, float]],
        control_points: Sequence[str],
        safety_distance: float,
        gains: Mapping[str, float],
    ) -> None:
        self.model = model
        nv = model.nv
        self.joint_dofs = [int(model.jnt_dofadr[model.joint(name).id]) for name, _, _ in joints]
        self.joint_safety = [(float(lo), float(hi)) for _, lo, hi in joints]
        self.ee = model.body(ee_body).id
        self.walls = [(np.asarray(n, dtype=float), float(d)) for n, d in walls]
        self.cps = [model.body(name).id for name in control_points]
        # The paper's partial Jacobian: only the joints before the control point's own joint move it.
        self.cp_columns = [int(model.jnt_dofadr[model.body_jntadr[b]]) for b in self.cps]
        self.safety_distance = safety_distance
        self.obstacles: list[np.ndarray | None] = [None] * len(self.cps)
        self.gains = gains
        count = 2 * len(self.joint_dofs) + len(self.walls) + len(self.cps)
        self.level = np.array([0] * (2 * len(self.joint_dofs)) + [1] * len(self.walls) + [2] * len(self.cps))
        self.J = np.zeros((count, nv))
        self.excess = np.zeros(count)  # σ − σ_s (negative: past the threshold)
        self.gain = np.zeros(count)
        self._jac = np.zeros((3, nv))

    def update(self, configuration: mink.Configuration, dt: float) -> None:
        """Evaluate every quantity at the configuration's data (after ``configuration.update``)."""
        data = configuration.data
        J, excess, gain = self.J, self.excess, self.gain
        J[:] = 0.0
        excess[:] = np.inf
        row = 0
        k_joint = min(self.gains["joint_limits"], 1.0 / dt)
        q = configuration.q
        for dof, (lo, hi) in zip(self.joint_dofs, self.joint_safety, strict=True):
            J[row, dof], excess[row], gain[row] = -1.0, hi - q[dof], k_joint
            J[row + 1, dof], excess[row + 1], gain[row + 1] = 1.0, q[dof] - lo, k_joint
            row += 2
        mujoco.mj_jacBody(self.model, data, self._jac, None, self.ee)
        p = data.xpos[self.ee]
        k_wall = min(self.gains["walls"], 1.0 / dt)
        for n, d in self.walls:
            J[row], excess[row], gain[row] = n @ self._jac, float(n @ p) - d, k_wall
            row += 1
        k_obstacle = min(self.gains["obstacles"], 1.0 / dt)
        for body, column, obstacle in zip(self.cps, self.cp_columns, self.obstacles, strict=True):
            if obstacle is not None:
                diff = obstacle - data.xpos[body]
                dist = float(np.linalg.norm(diff))
                if dist > 0.0:
                    mujoco.mj_jacBody(self.model, data, self._jac, None, body)
                    self._jac[:, column:] = 0.0
                    J[row] = -(diff / dist) @ self._jac
                    excess[row], gain[row] = dist - self.safety_distance, k_obstacle
            row += 1


class _SafetyLimit(mink.Limit):
    r""":math:`-J\Delta q \le \max(0, K\,dt\,(\sigma - \sigma_s))`: Δq = 0 is always feasible."""

    def __init__(self, rows: _SafetyRows) -> None:
        self.rows = rows

    def compute_qp_inequalities(self, configuration: mink.Configuration, dt: float) -> mink.Constraint:
        """The rows of the quantities that can be evaluated (an obstacle out of range gives none)."""
        r = self.rows
        live = np.isfinite(r.excess)
        return mink.Constraint(G=-r.J[live], h=np.maximum(r.gain[live] * dt * r.excess[live], 0.0))


class _SafetyReturn(mink.Task):
    r"""Soft return: past its threshold a quantity comes back at its reference rate.

    :math:`J\Delta q \to -K\,dt\,(\sigma - \sigma_s)`, costs ρ³, ρ², ρ for joint limits, walls,
    obstacles (the EE task has cost 1).
    """

    def __init__(self, rows: _SafetyRows, level_cost_ratio: float) -> None:
        super().__init__(cost=level_cost_ratio ** (3 - rows.level).astype(float), gain=1.0)
        self.rows = rows
        self.dt = 0.01

    def compute_error(self, configuration: mink.Configuration) -> np.ndarray:
        r""":math:`K\,dt\,(\sigma - \sigma_s)` for a quantity past its threshold, 0 otherwise."""
        r = self.rows
        past = np.isfinite(r.excess) & (r.excess < 0.0)
        return np.where(past, r.gain * self.dt * np.where(past, r.excess, 0.0), 0.0)

    def compute_jacobian(self, configuration: mink.Configuration) -> np.ndarray:
        """J of the quantities past their threshold, zero rows otherwise."""
        r = self.rows
        past = np.isfinite(r.excess) & (r.excess < 0.0)
        return np.where(past[:, None], r.J, 0.0)


class MinkCase2:
    """Paper case 2 as a mink program: one call of :meth:`step` is one control step.

    Args:
        model: The arm's MuJoCo model (``robot.mj_model``).
        v_max: Joint velocity limits by MuJoCo joint name [rad/s].
        joints: (MuJoCo joint name, safety lower, safety upper) of each joint limit [rad].
        walls: (normal n, offset d) of each wall, σ = nᵀp − d ≥ 0 for the EE.
        ee_body: MuJoCo body of the EE (position task and walls).
        control_bodies: MuJoCo bodies of the obstacle control points, in :meth:`set_scene` order.
        safety_distance: Safety threshold of the obstacle distances [m].
        gains: Gains [1/s] of ``"joint_limits"``, ``"walls"``, ``"obstacles"``, ``"position"``.
        level_cost_ratio: ρ of the soft return (levels above the EE task: ρ, ρ², ρ³).
    """

    name = "mink-native"

    def __init__(
        self,
        model: mujoco.MjModel,
        v_max: Mapping[str, float],
        joints: Sequence[tuple[str, float, float]],
        walls: Sequence[tuple[np.ndarray, float]],
        ee_body: str,
        control_bodies: Sequence[str],
        safety_distance: float = 0.35,
        gains: Mapping[str, float] | None = None,
        level_cost_ratio: float = 10.0,
    ) -> None:
        self.gains = {"joint_limits": 1.0, "walls": 1.0, "obstacles": 1.0, "position": 1.0, **(gains or {})}
        self.configuration = mink.Configuration(model)
        self.rows = _SafetyRows(model, joints, ee_body, walls, control_bodies, safety_distance, self.gains)
        self.ee_task = mink.FrameTask(ee_body, "body", position_cost=1.0, orientation_cost=0.0)
        self.safety_return = _SafetyReturn(self.rows, level_cost_ratio)
        self.tasks = [self.ee_task, self.safety_return]
        self.limits = [
            mink.ConfigurationLimit(model, gain=0.95),
            mink.VelocityLimit(model, dict(v_max)),
            _SafetyLimit(self.rows),
        ]
        self.parts_s: tuple[float, float, float] = (0.0, 0.0, 0.0)
        """(row updates, problem build, solver) of the last :meth:`step` [s]."""

    def set_scene(self, obstacles: Sequence[np.ndarray | None], target: np.ndarray) -> None:
        """Closest obstacle point per control point (``control_bodies`` order; None: out of range), EE target [m]."""
        self.rows.obstacles = [None if o is None else np.asarray(o, dtype=float) for o in obstacles]
        self._target = np.asarray(target, dtype=float)

    def step(self, q: np.ndarray, dt: float) -> np.ndarray:
        """Joint velocity [rad/s] of one control step at ``q``; :attr:`parts_s` its three parts.

        Raises:
            mink.NoSolutionFound: DAQP found no solution (as ``mink.solve_ik`` raises).
        """
        t0 = time.perf_counter()
        configuration = self.configuration
        configuration.update(q)
        self.rows.update(configuration, dt)
        self.safety_return.dt = dt
        self.ee_task.gain = min(1.0, self.gains["position"] * dt)
        # Position only: the target keeps the frame's current orientation (SE(3) log couples the two).
        current = configuration.get_transform_frame_to_world(self.ee_task.frame_name, "body")
        self.ee_task.set_target(mink.SE3.from_rotation_and_translation(current.rotation(), self._target))
        t1 = time.perf_counter()
        configuration.check_limits(safety_break=False)  # mink.solve_ik's first call, then its problem
        problem = mink.build_ik(configuration, self.tasks, dt, 1e-12, self.limits)
        t2 = time.perf_counter()
        solution = qpsolvers.solve_problem(problem, solver="daqp")
        t3 = time.perf_counter()
        self.parts_s = (t1 - t0, t2 - t1, t3 - t2)
        if not solution.found or solution.x is None:
            raise mink.NoSolutionFound("daqp")
        return solution.x / dt


__all__ = ["MinkCase2"]

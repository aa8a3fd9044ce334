r"""The mink peer: the same hierarchy handed to :func:`mink.solve_ik` (weighted, not strict, priorities).

mink solves one QP per step over the configuration displacement :math:`\Delta q = \dot q\,dt`:

.. math::
    \min_{\Delta q}\ \sum_i c_i^2 \|J_i \Delta q + \alpha_i e_i\|^2 + \mu \|\Delta q\|^2
    \quad \text{s.t.}\quad G \Delta q \le h

and :func:`mink.solve_ik` returns :math:`v = \Delta q / dt` [rad/s]: the velocity is per second,
``dt`` only scales the constraints (``VelocityLimit`` gives :math:`|\Delta q| \le v_{max} dt`) and
the damping :math:`\mu` multiplies :math:`\|\Delta q\|^2` (unitless relative to the task terms).

How our tasks map onto mink:

* Position / orientation / pose tasks become a :class:`mink.FrameTask` on the same MJCF body
  (position cost only for a position task, orientation cost only for an orientation task). The
  CLIK reference :math:`r = \dot\sigma_d + K\tilde\sigma` of our task becomes the frame target
  :math:`p_t = p + r_p\,dt/\alpha`, :math:`R_t = \mathrm{Exp}(r_\omega dt/\alpha) R` with
  :math:`\alpha = \min(1, K dt)` the mink gain, so that :math:`\alpha (p_t - p) = r_p\,dt`: with no
  feedforward and :math:`K dt \le 1` the target is exactly :math:`p_d`.
* Any other equality task (e.g. manipulability) becomes a small :class:`mink.Task` adapter with
  error :math:`e = -r\,dt` and the task's own Jacobian.
* Every set-based task becomes a row pair of :class:`SetTaskLimit` (a :class:`mink.Limit`):
  :math:`\dot\sigma_l\,dt \le J \Delta q \le \dot\sigma_u\,dt` from :meth:`tpik.tasks.SetTask.velocity_bounds`.
  These are *hard* constraints without slack: when they cannot all be met mink finds no solution
  and the step is reported FAILED with a zero velocity.
* Joint position limits of the model: :class:`mink.ConfigurationLimit`; joint velocity limits
  ``robot.v_max``: :class:`mink.VelocityLimit`.

Priorities are weights (mink's nature): the equality levels, highest first, get the costs
:math:`c_k = \rho^{-k}` (:math:`\rho` = ``level_cost_ratio``, default 10, i.e. a factor 100 per
level on the squared residual). Set-task levels are constraints whatever their level.

The set-based task Jacobians come from pinocchio through our :class:`~robots.Kinematics`;
mink computes the frame Jacobians from MuJoCo. Both read the same MJCF file.

A step calls :func:`mink.build_ik` then :func:`qpsolvers.solve_problem` and divides by ``dt``,
which is all :func:`mink.solve_ik` does besides a limit check that only logs: the build and
solve times can so be reported apart (``tests/qp_baseline/test_mink_peer.py`` checks the
velocity equals ``mink.solve_ik``'s). mink's failures (no solution, an exception, a velocity
outside the limits by more than ``tolerance``) give a FAILED step with zero velocity.
"""

from __future__ import annotations

import math
import time
import warnings
from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import Any

import mink
import numpy as np
import qpsolvers

from qp_baseline.exceptions import InvalidSettings, UnknownSolver
from qp_baseline.hqp import available_qp_solvers, backend_iterations, backend_kwargs, probe_settings
from qp_baseline.time_limits import TimeLimited
from robots import Kinematics, Robot
from tpik.hierarchy import Hierarchy
from tpik.step_result import SolveStatus, StepResult, failed
from tpik.tasks import OrientationTask, PoseTask, PositionTask, SetTask, Task, TaskState


@dataclass(frozen=True)
class MinkSettings:
    r"""Settings of the mink peer (the ``[methods.mink]`` table of a config).

    Attributes:
        solver: QP backend mink hands its problem to (any name of
            :func:`qp_baseline.hqp.available_qp_solvers`).
        damping: mink's Levenberg–Marquardt damping µ on :math:`\|\Delta q\|^2` (mink's default).
        level_cost_ratio: ρ ≥ 1: the k-th equality level (0 = highest) has cost ρ^-k.
        configuration_limit_gain: Gain in (0, 1] of :class:`mink.ConfigurationLimit`.
        tolerance: Constraint tolerance [rad/s or m/s] of the check on the returned velocity.
        qp_settings: Keyword arguments forwarded to the QP backend.
    """

    solver: str = "daqp"
    damping: float = 1e-12
    level_cost_ratio: float = 10.0
    configuration_limit_gain: float = 0.95
    tolerance: float = 1e-6
    qp_settings: Mapping[str, Any] | None = None

    @classmethod
    def from_dict(cls, data: Mapping[str, Any] | None) -> MinkSettings:
        """Validate a plain dict; unknown keys and bad values raise :class:`InvalidSettings`."""
        data = dict(data or {})
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise InvalidSettings(
                "mink", f"unknown setting '{unknown[0]}'; known: {', '.join(sorted(known))}", unknown[0]
            )
        settings = cls(**data)
        settings.check()
        return settings

    def check(self) -> None:
        """Raise :class:`InvalidSettings` naming the first bad value."""
        if self.solver not in available_qp_solvers():
            raise UnknownSolver(self.solver, available_qp_solvers())
        checks = (
            ("damping", self.damping, lambda v: v >= 0.0, ">= 0"),
            ("level_cost_ratio", self.level_cost_ratio, lambda v: v >= 1.0, ">= 1"),
            ("configuration_limit_gain", self.configuration_limit_gain, lambda v: 0.0 < v <= 1.0, "in (0, 1]"),
            ("tolerance", self.tolerance, lambda v: v > 0.0, "> 0"),
        )
        for key, value, ok, expected in checks:
            if not isinstance(value, int | float) or not math.isfinite(value) or not ok(value):
                raise InvalidSettings("mink", f"setting '{key}' must be a finite number {expected}, got {value!r}", key)
        if self.qp_settings is not None and not isinstance(self.qp_settings, Mapping):
            raise InvalidSettings("mink", f"'qp_settings' must be a table, got {self.qp_settings!r}", "qp_settings")


class SetTaskLimit(mink.Limit):
    r"""Set-based tasks as a mink limit: :math:`\dot\sigma_l\,dt \le J \Delta q \le \dot\sigma_u\,dt`.

    The rows are loaded each step by :meth:`set_rows` from the task states and
    :meth:`tpik.tasks.SetTask.velocity_bounds`; infinite bounds give no row.
    """

    def __init__(self, nv: int) -> None:
        self.nv = nv
        self._G = np.zeros((0, nv))
        self._h = np.zeros(0)
        self.names: list[str] = []

    def set_rows(self, G: np.ndarray, h: np.ndarray, names: list[str]) -> None:
        """Load ``G q̇ ≤ h`` [h in task units per second]; ``names[i]`` is row i's task."""
        self._G, self._h, self.names = G, h, names

    def compute_qp_inequalities(self, configuration: mink.Configuration, dt: float) -> mink.Constraint:
        r"""Rows :math:`G \Delta q \le h\,dt` (``configuration`` is unused: rows come from our tasks)."""
        del configuration
        if self._h.size == 0:
            return mink.Constraint()
        return mink.Constraint(G=self._G, h=self._h * dt)


class _StateTask(mink.Task):
    """Any equality task of ours as a mink task: error ``-r dt``, our Jacobian."""

    def __init__(self, dim: int, cost: float) -> None:
        super().__init__(cost=np.full(dim, cost), gain=1.0)
        self.error = np.zeros(dim)
        self.jacobian = np.zeros((dim, 0))

    def compute_error(self, configuration: mink.Configuration) -> np.ndarray:
        """The stored error ``-r dt``."""
        return self.error

    def compute_jacobian(self, configuration: mink.Configuration) -> np.ndarray:
        """The stored Jacobian (from pinocchio)."""
        return self.jacobian


@dataclass
class _Adapter:
    """One of our equality tasks and the mink task that stands for it."""

    task: Task
    mink_task: mink.Task
    kind: str  # "position" | "orientation" | "pose" | "state"
    body: str = ""


def _so3_exp(omega: np.ndarray) -> np.ndarray:
    """Rodrigues' formula: rotation matrix of the rotation vector ``omega`` [rad]."""
    angle = float(np.linalg.norm(omega))
    if angle < 1e-12:
        return np.eye(3)
    k = omega / angle
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + math.sin(angle) * K + (1.0 - math.cos(angle)) * (K @ K)


class MinkSolver(TimeLimited):
    """The mink peer behind the shared ``solve(hierarchy, kin, dt)`` interface.

    Args:
        robot: The robot; mink gets ``robot.mj_model`` (same MJCF as pinocchio).
        settings: A plain dict validated by :meth:`MinkSettings.from_dict`.
        name: Method name reported in results.

    Raises:
        UnknownSolver: ``settings["solver"]`` is not an installed QP backend.
        InvalidSettings: Unknown key or bad value.
    """

    def __init__(self, robot: Robot, settings: Mapping[str, Any] | None = None, name: str = "mink") -> None:
        self.robot = robot
        self.name = name
        self.settings = MinkSettings.from_dict(settings)
        self._qp_kwargs = backend_kwargs(self.settings.solver, self.settings.qp_settings or {})
        self.configuration = mink.Configuration(robot.mj_model)
        nv = robot.nq
        self._limit_rows = SetTaskLimit(nv)
        velocities = {robot.joint_names[i]: float(robot.v_max[i]) for i in range(nv)}
        self._limits: list[mink.Limit] = [
            mink.ConfigurationLimit(robot.mj_model, gain=self.settings.configuration_limit_gain),
            mink.VelocityLimit(robot.mj_model, velocities),
            self._limit_rows,
        ]
        self._hierarchy: Hierarchy | None = None
        self._adapters: list[_Adapter] = []
        self._set_tasks: list[SetTask] = []
        self._check_qp_settings()

    def _check_qp_settings(self) -> None:
        """Solve a tiny QP with the backend settings so a bad one fails here, not mid-run."""
        probe_settings(self.settings.solver, self.settings.qp_settings or {})

    def _prepare(self, hierarchy: Hierarchy) -> None:
        """Build the mink tasks of a hierarchy once (rebuilt only for a new hierarchy object)."""
        if hierarchy is self._hierarchy:
            return
        adapters: list[_Adapter] = []
        set_tasks: list[SetTask] = []
        eq_level = 0
        for level in hierarchy.levels:
            has_equality = False
            cost = self.settings.level_cost_ratio ** (-eq_level)
            for task in level.tasks:
                if isinstance(task, SetTask):
                    set_tasks.append(task)
                    continue
                has_equality = True
                adapters.append(self._adapter(task, cost))
            if has_equality:
                eq_level += 1
        self._adapters = adapters
        self._set_tasks = set_tasks
        self._hierarchy = hierarchy

    def _adapter(self, task: Task, cost: float) -> _Adapter:
        frame_kinds: list[tuple[type[Task], str, float, float]] = [
            (PoseTask, "pose", cost, cost),
            (PositionTask, "position", cost, 0.0),
            (OrientationTask, "orientation", 0.0, cost),
        ]
        for cls, kind, pos_cost, rot_cost in frame_kinds:
            if isinstance(task, cls):
                frame = str(task.frame)  # type: ignore[attr-defined]
                self.robot.frame_id(frame)
                prefix = self.robot.spec.prefix
                body = frame if frame.startswith(prefix) else prefix + frame
                frame_task = mink.FrameTask(body, "body", position_cost=pos_cost, orientation_cost=rot_cost)
                return _Adapter(task, frame_task, kind, body)
        return _Adapter(task, _StateTask(task.dim, cost), "state")

    def _update_task(self, adapter: _Adapter, state: TaskState, dt: float) -> None:
        task = adapter.task
        r = state.feedforward + task.gain * state.error  # CLIK reference (paper eq. 2)
        if adapter.kind == "state":
            stask = adapter.mink_task
            assert isinstance(stask, _StateTask)
            stask.error = -r * dt
            stask.jacobian = state.jacobian
            return
        alpha = min(1.0, task.gain * dt)
        frame = self.configuration.get_transform_frame_to_world(adapter.body, "body").as_matrix()
        p, R = frame[:3, 3], frame[:3, :3]
        scale = dt / alpha
        if adapter.kind == "position":
            p_t, R_t = p + r * scale, R
        elif adapter.kind == "orientation":
            p_t, R_t = p, _so3_exp(r * scale) @ R
        else:
            p_t, R_t = p + r[:3] * scale, _so3_exp(r[3:] * scale) @ R
        target = np.eye(4)
        target[:3, :3], target[:3, 3] = R_t, p_t
        ftask = adapter.mink_task
        assert isinstance(ftask, mink.FrameTask)
        ftask.gain = alpha
        ftask.set_target(mink.SE3.from_matrix(target))

    def solve(self, hierarchy: Hierarchy, kin: Kinematics, dt: float) -> StepResult:
        """One step: build mink's QP at ``kin.q`` and solve it with the configured backend.

        Args:
            hierarchy: The shared hierarchy (only read).
            kin: Kinematics snapshot at the current configuration.
            dt: Control period [s].

        Returns:
            A :class:`StepResult`; FAILED with zero velocity when mink finds no solution or
            its velocity breaks a limit by more than ``tolerance``.
        """
        n = self.robot.nq
        if not (math.isfinite(dt) and dt > 0.0):
            return failed(n, f"dt must be finite and > 0, got {dt}")
        t0 = time.perf_counter()
        if self.budget is not None:
            self.budget.start()
        try:
            self._prepare(hierarchy)
            self.configuration.update(kin.q)
            for adapter in self._adapters:
                self._update_task(adapter, adapter.task.compute_state(kin), dt)
            rows, bounds, names = [], [], []
            for task in self._set_tasks:
                state = task.compute_state(kin)
                lo, hi = task.velocity_bounds(state, dt)
                jac = state.jacobian[0]
                if math.isfinite(hi):
                    rows.append(jac)
                    bounds.append(hi)
                    names.append(task.name)
                if math.isfinite(lo):
                    rows.append(-jac)
                    bounds.append(-lo)
                    names.append(task.name)
            G = np.array(rows) if rows else np.zeros((0, n))
            self._limit_rows.set_rows(G, np.array(bounds, dtype=float), names)
            tasks = [a.mink_task for a in self._adapters]
            problem = mink.build_ik(self.configuration, tasks, dt, self.settings.damping, self._limits)
        except Exception as exc:  # noqa: BLE001 - mink errors, its asserts, a task that cannot be evaluated
            return failed(n, f"mink could not build the problem: {type(exc).__name__}: {exc}")
        t1 = time.perf_counter()
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                kwargs = self._budget_kwargs(self.settings.solver, self._qp_kwargs)
                solution = qpsolvers.solve_problem(problem, solver=self.settings.solver, **kwargs)
        except Exception as exc:  # noqa: BLE001 - any backend error becomes a FAILED step
            res = failed(n, f"mink ({self.settings.solver}) raised {type(exc).__name__}: {exc}")
            res.build_time_s, res.solve_time_s = t1 - t0, time.perf_counter() - t1
            return res
        t2 = time.perf_counter()
        result = self._finish(solution, G, dt)
        result.build_time_s, result.solve_time_s = t1 - t0, t2 - t1
        return result

    def _finish(self, solution: qpsolvers.Solution, G: np.ndarray, dt: float) -> StepResult:
        n = self.robot.nq
        x = solution.x
        iterations = backend_iterations(solution)
        if not solution.found or x is None or x.shape != (n,) or not np.all(np.isfinite(x)):
            return failed(n, f"mink: QP solver {self.settings.solver} found no solution", iterations=iterations)
        qdot = x / dt  # mink.solve_ik returns Δq / dt: a velocity [rad/s]
        tol = self.settings.tolerance
        excess = float(np.max(np.abs(qdot) - self.robot.v_max))
        h = self._limit_rows._h
        row_excess = float(np.max(G @ qdot - h)) if h.size else -math.inf
        if excess > tol or row_excess > tol:
            return failed(
                n,
                f"mink: solution breaks a limit (velocity by {excess:.3g}, set rows by {row_excess:.3g})",
                iterations=iterations,
            )
        qdot = np.clip(qdot, -self.robot.v_max, self.robot.v_max)
        active: list[str] = []
        if h.size:
            binding = G @ qdot >= h - tol
            for name, hit in zip(self._limit_rows.names, binding, strict=True):
                if hit and name not in active:
                    active.append(name)
        return StepResult(qdot, SolveStatus.OK, tuple(active), extras={"iterations": iterations})

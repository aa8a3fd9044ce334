r"""Hierarchical QP: the tpik hierarchy solved as a lexicographic cascade of QPs (Kanoun, Escande).

Level :math:`k` (highest first) holds equality tasks, stacked as :math:`J_k,\ r_k` with the CLIK
reference :math:`r = \dot\sigma_d + K\tilde\sigma` (paper eq. 2), and set-based tasks, whose
reference rates give rows :math:`G_k \dot q \le h_k` (a finite upper bound
:math:`J\dot q \le \dot\sigma_u`, a finite lower one :math:`-J\dot q \le -\dot\sigma_l`; a
non-finite σ, e.g. no obstacle, gives no row; :mod:`qp_baseline.set_rows`, shared with mink).
Both references come from :mod:`tpik.reference`, the one every method uses (gain cap
``gain_cap``). Each level solves

.. math::
    \min_{\dot q,\ w_k}\ \|J_k \dot q - r_k\|^2 + \|w_k\|^2 + \epsilon \|\dot q\|^2
    \quad\text{s.t.}\quad
    \begin{cases}
      G_k \dot q - w_k \le h_k,\ \ w_k \ge 0 & \text{(this level, slack } w_k)\\
      G_j \dot q \le h_j + w_j^*,\ \ j < k & \text{(earlier set rows, relaxed by their optimal slack)}\\
      J_j \dot q = J_j \dot q^*_{k-1},\ \ j < k & \text{(earlier equality rows, fixed)}\\
      \underline{v} \le \dot q \le \overline{v} & \text{(hard)}
    \end{cases}

with the hard joint box :math:`\underline v = \max(-v_{max}, (q_{min} - q)/dt)`,
:math:`\overline v = \min(v_{max}, (q_{max} - q)/dt)` (:func:`default_limits`; the position part
clipped into :math:`[-v_{max}, v_{max}]` so the box is never empty). A lower level can therefore
never degrade a higher one. The regularisation :math:`\epsilon\|\dot q\|^2` (``regularization``,
default 1e-9) makes every level's Hessian positive definite; without inequalities the cascade
then equals the Siciliano–Slotine null-space solution up to :math:`O(\epsilon/\sigma_{min}^2)`.

The parts, one job each:

* :mod:`qp_baseline.hqp_settings`: the options, and the backend's defaults filled in;
* :mod:`qp_baseline.hqp_layout`: the hierarchy's rows, evaluated once per step (a set row that
  cannot bind inside the box is dropped: exact);
* :mod:`qp_baseline.hqp_cascade`: the levels in priority order, earlier equality rows eliminated
  in a null-space basis, the final min-norm level (inexact backends need it: ``min_norm_level``);
* :mod:`qp_baseline.hqp_level_solve`: one level, its unconstrained minimiser first
  (``unconstrained_first``; ``extras["qp_calls"]`` counts the levels that called the backend);
* :mod:`qp_baseline.hqp_level`: one level's QP in :math:`x = [z;\ w]`, feasible by construction;
* :mod:`qp_baseline.hqp_attempts` and :mod:`qp_baseline.hqp_verify`: one QP solved, every answer
  certified (:mod:`qp_baseline.certificate`) whatever status the backend reported, polished
  (:mod:`qp_baseline.polish`) and retried when it is not;
* :mod:`qp_baseline.hqp_report`: the step's result.

A level without a usable answer is given up (level 0: FAILED with zero velocity; a later level:
DEGRADED keeping the levels above it); a usable answer that is not certified is kept, the step
DEGRADED (FAILED at level 0). :attr:`HqpSolver.qp_log` records the level QPs
(:class:`~qp_baseline.level_qp.LevelQp`), e.g. for a qpbenchmark export.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np
import qpsolvers

from qp_baseline.backend_call import (
    available_qp_solvers,
    backend_iterations,
    backend_kwargs,
    backend_problem,
    check_solver,
    probe_settings,
)
from qp_baseline.backend_call import solve_quietly as _solve_quietly
from qp_baseline.backends import BACKENDS
from qp_baseline.cascade_kernels import warm_up as warm_up_kernels
from qp_baseline.certificate import Tolerances
from qp_baseline.certificate_dense import warm_up as warm_up_certificate
from qp_baseline.exceptions import InvalidSettings
from qp_baseline.hqp_attempts import RETRY_REGULARIZATION, solve_checked
from qp_baseline.hqp_cascade import Cascade, CascadeState
from qp_baseline.hqp_layout import HierarchyLayout
from qp_baseline.hqp_level import LevelQpBuilder
from qp_baseline.hqp_level_solve import CascadeMemory, LevelSolver, SolveTime
from qp_baseline.hqp_report import failed_result, step_result
from qp_baseline.hqp_settings import CascadeSettings, HqpSettings, default_limits, split_settings
from qp_baseline.hqp_verify import AnswerJudge
from qp_baseline.level_qp import LevelAnswer, LevelQp, QpCheck
from qp_baseline.qp_problem import DenseProblem, dense_problem
from qp_baseline.set_rows import warm_up_rows
from qp_baseline.time_limits import TimeLimited
from robots import Kinematics, Robot
from tpik.hierarchy import Hierarchy
from tpik.limits import Limit, compose_box
from tpik.reference import ControlReference
from tpik.step_result import StepResult, failed

__all__ = [
    "RETRY_REGULARIZATION",
    "HqpSettings",
    "HqpSolver",
    "available_qp_solvers",
    "backend_iterations",
    "backend_kwargs",
    "default_limits",
    "probe_settings",
    "split_settings",
]


class HqpSolver(TimeLimited):
    """Hierarchical QP over a tpik :class:`~tpik.hierarchy.Hierarchy`, any supported backend.

    Args:
        robot: The robot (velocity and position limits).
        solver: Backend name, one of :func:`available_qp_solvers`.
        settings: Cascade options (fields of :class:`HqpSettings`) and backend keyword arguments in
            one table; backend arguments override the backend's defaults (:data:`qp_baseline.backends.BACKENDS`).
        name: Method name reported in results (default ``hqp-<solver>``).
        limits: Joint limits (:mod:`tpik.limits`) composed in order into the hard box of every
            level; :func:`default_limits` (velocity, then position) when None.

    Raises:
        UnknownSolver: ``solver`` is not available (the message lists what is).
        InvalidSettings: A setting is unknown to the backend or has a bad value.
    """

    def __init__(
        self,
        robot: Robot,
        solver: str = "daqp",
        settings: Mapping[str, Any] | None = None,
        name: str | None = None,
        limits: Sequence[Limit] | None = None,
    ) -> None:
        check_solver(solver)
        self.robot = robot
        self.limits: tuple[Limit, ...] = default_limits(robot) if limits is None else tuple(limits)
        """The hard box, composed in order (:func:`tpik.limits.compose_box`)."""
        if not self.limits:
            raise InvalidSettings(solver, "HQP needs at least one limit (its hard box)")
        self.solver = solver
        self.name = name or f"hqp-{solver}"
        self.options, user_kwargs = split_settings(solver, settings)
        self.reference = ControlReference(gain_cap=self.options.gain_cap)
        probe_settings(solver, user_kwargs)
        backend = BACKENDS[solver]
        self.qp_settings: dict[str, Any] = {**backend.defaults, **user_kwargs}
        """The backend's settings: its defaults, overridden by the user's."""
        self._kwargs = backend_kwargs(solver, self.qp_settings)
        self._retry_kwargs = backend_kwargs(solver, {**self.qp_settings, **backend.retry})
        self.cascade_settings = CascadeSettings.resolve(self.options, backend)
        """The options with the backend's defaults filled in."""
        warm_up_certificate()  # the compiled certificate and kernels are loaded now, not at the first step
        warm_up_kernels(robot.nq)
        warm_up_rows(robot.nq)
        self.qp_log: list[LevelQp] | None = None
        """When a list, every backend-solved level QP is appended to it (:class:`LevelQp`)."""
        self._judge = AnswerJudge(solver, self.cascade_settings)
        self._builder = LevelQpBuilder(robot.nq, self.options.regularization)
        self._clock = SolveTime()
        self._hierarchy: Hierarchy | None = None
        self._layout: HierarchyLayout | None = None
        self._memory = CascadeMemory()

    def __repr__(self) -> str:
        return f"HqpSolver(name={self.name!r}, solver={self.solver!r}, settings={self.qp_settings})"

    @property
    def tolerance(self) -> float:
        """Accepted constraint violation of a backend answer [rad/s or m/s]."""
        return self.cascade_settings.tolerance

    @property
    def slack_tolerance(self) -> float:
        """A slack above this makes the step DEGRADED [task unit / s]."""
        return self.cascade_settings.slack_tolerance

    @property
    def slack_margin(self) -> float:
        """Margin δ of a relaxed row and of the min-norm level's rows."""
        return self.cascade_settings.slack_margin

    @property
    def min_norm_level(self) -> bool:
        """Whether the final min-norm level is solved."""
        return self.cascade_settings.min_norm_level

    @property
    def objective_tolerance(self) -> float:
        """Accepted error of a level's residual norm, relative to 1 + ρ."""
        return self.cascade_settings.objective_tolerance

    @property
    def certificate_tolerances(self) -> Tolerances:
        """The certificate's thresholds."""
        return self.cascade_settings.certificate_tolerances

    @property
    def warm_start(self) -> bool:
        """Whether each level starts from its previous-step answer."""
        return self.cascade_settings.warm_start

    def solve(self, hierarchy: Hierarchy, kin: Kinematics, dt: float) -> StepResult:
        """One control step of the cascade.

        Args:
            hierarchy: The shared hierarchy (only read).
            kin: Kinematics snapshot at the current configuration.
            dt: Control period [s].

        Returns:
            OK; DEGRADED (a slack above ``slack_tolerance``, or a lower level given up or not
            certified); or FAILED with zero velocity. ``build_time_s`` covers task evaluation and
            problem assembly, ``solve_time_s`` the backend calls and the unconstrained linear
            solves; ``extras`` as :mod:`qp_baseline.hqp_report` lists them.
        """
        if not (math.isfinite(dt) and dt > 0.0):
            return failed(self.robot.nq, f"dt must be finite and > 0, got {dt}")
        t_start = time.perf_counter()
        if self.budget is not None:
            self.budget.start()
        self._clock.seconds = 0.0
        layout = self._prepare(hierarchy)
        lb, ub = compose_box(self.limits, kin.q, dt)
        cuts = layout.evaluate(kin, dt, lb, ub, self.name)  # a task error (tpik.TpikError) propagates
        state = CascadeState(np.zeros(self.robot.nq), layout.h.copy(), lb, ub, cuts)
        settings = self.cascade_settings
        levels = LevelSolver(self._builder, settings, self._memory, self._clock, self.solve_problem, self.qp_log)
        cascade = Cascade(layout, settings, levels, self.name)
        failure = cascade.run(state)
        total_s, solve_s = time.perf_counter() - t_start, self._clock.seconds
        if failure is None:
            result = step_result(state, cascade, settings.slack_tolerance, total_s, solve_s)
        else:
            result = failed_result(failure, cascade, self.robot.nq, total_s, solve_s)
        for limit in self.limits:
            limit.observe(result.qdot)
        return result

    def _prepare(self, hierarchy: Hierarchy) -> HierarchyLayout:
        """The layout of ``hierarchy``, built once per hierarchy object (the levels' memory with it)."""
        if self._layout is None or hierarchy is not self._hierarchy:
            self._layout = HierarchyLayout(hierarchy, self.robot, self.reference)
            self._memory = CascadeMemory()
            self._hierarchy = hierarchy
        return self._layout

    def solve_problem(
        self, problem: qpsolvers.Problem, check: QpCheck, level: int = 0, initvals: np.ndarray | None = None
    ) -> LevelAnswer:
        """Solve one QP, checked (:mod:`qp_baseline.hqp_attempts`, :mod:`qp_baseline.hqp_verify`).

        Every answer is judged by its certificate (with ``certify`` on), whatever status the
        backend reported; a rejected one is retried once with the backend's retry settings (with
        ``retry`` on). The cascade solves each level QP through this method.

        Args:
            problem: The QP.
            check: How its answers are judged.
            level: Priority level reported by :class:`~qp_baseline.exceptions.NoSolutionFound`.
            initvals: Warm start of the first attempt (backends that take one: OSQP, ProxQP).

        Raises:
            NoSolutionFound: No attempt gave a usable answer.
        """
        attempts = [self._kwargs, self._retry_kwargs] if self.options.retry else [self._kwargs]
        return solve_checked(dense_problem(problem), check, level, initvals, attempts, self._call_backend, self._judge)

    def solve_qp(
        self,
        P: np.ndarray,
        q: np.ndarray,
        G: np.ndarray | None,
        h: np.ndarray | None,
        lb: np.ndarray,
        ub: np.ndarray,
        x0: np.ndarray,
        f0: float | None = None,
        level: int = 0,
        level_value: Callable[[np.ndarray], float] | None = None,
        initvals: np.ndarray | None = None,
        refine: Callable[[np.ndarray], np.ndarray] | None = None,
        curvature: np.ndarray | None = None,
        modulus: float | None = None,
    ) -> LevelAnswer:
        r""":meth:`solve_problem` of :math:`\min \tfrac12 x^TPx + q^Tx` s.t. :math:`Gx \le h,\ lb \le x \le ub`.

        Args:
            P: Positive definite cost matrix. Shape (d, d).
            q: Cost vector. Shape (d,).
            G: Inequality matrix, or None. Shape (m, d).
            h: Inequality bounds, or None. Shape (m,).
            lb: Lower bounds of x (finite). Shape (d,).
            ub: Upper bounds of x (finite). Shape (d,).
            x0: A feasible point. Shape (d,).
            f0: Objective at ``x0`` (computed when None).
            level: Priority level reported by :class:`~qp_baseline.exceptions.NoSolutionFound`.
            level_value: As :attr:`QpCheck.level_value <qp_baseline.level_qp.QpCheck>`.
            initvals: Warm start of the first attempt.
            refine: As :class:`~qp_baseline.level_qp.QpCheck`.
            curvature: As :class:`~qp_baseline.level_qp.QpCheck`.
            modulus: As :class:`~qp_baseline.level_qp.QpCheck`.

        Raises:
            NoSolutionFound: No attempt gave a usable answer.
        """
        if G is None or h is None:
            G, h = np.zeros((0, q.shape[0])), np.zeros(0)
        if f0 is None:
            f0 = float(x0 @ (0.5 * (P @ x0) + q))
        check = QpCheck(x0, f0, level_value, refine, curvature, modulus)
        return self.solve_problem(DenseProblem(P, q, G, h, lb=lb, ub=ub), check, level, initvals)

    def _call_backend(
        self, problem: DenseProblem, initvals: np.ndarray | None, kwargs: Mapping[str, Any]
    ) -> qpsolvers.Solution:
        """One backend call, timed into the step's solve time, limited to the call's budget (if any)."""
        kwargs = self._budget_kwargs(self.solver, kwargs)
        posed = backend_problem(problem, self.solver)
        t0 = time.perf_counter()
        try:
            return _solve_quietly(posed, self.solver, BACKENDS[self.solver].prints, initvals=initvals, **kwargs)
        finally:
            self._clock.seconds += time.perf_counter() - t0

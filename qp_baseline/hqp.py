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
:math:`\overline v = \min(v_{max}, (q_{max} - q)/dt)` (infinite position limits skipped; the
position part is clipped into :math:`[-v_{max}, v_{max}]` so the box is never empty, even when
``q`` is already outside its limits). A lower level can therefore never degrade a higher one.

Implementation choices:

* **Equality rows of earlier levels are eliminated**, not passed as constraints: the unknown is
  :math:`\dot q = \dot q^*_{k-1} + Z z` with :math:`Z` an orthonormal basis of the null space of
  all earlier equality Jacobians (from an SVD, relative rank tolerance ``rank_tolerance``). No
  backend ever sees linearly dependent equality constraints, and a level whose null space is
  empty is not solved at all.
* **Regularisation** :math:`\epsilon\|\dot q\|^2` (``regularization``, default 1e-9, unitless on
  squared rad/s) makes every level's Hessian positive definite (quadprog requires it, DAQP fails
  on near-singular Hessians). Without inequalities the cascade then equals the Siciliano–Slotine
  null-space solution up to :math:`O(\epsilon/\sigma_{min}^2)`.
* **Min-norm level**: after the last task level the remaining freedom is fixed by one more level,
  :math:`\min\|\dot q\|^2` under every earlier constraint. Interior-point and first-order backends
  (OSQP, ProxQP, Clarabel, PIQP) stop on tolerances far above ε·‖q̇‖², so the null-space
  component of their answer is otherwise arbitrary; active-set backends (DAQP, quadprog) solve the
  ε-regularised KKT system exactly and skip it by default (``min_norm_level``).
* **Slacks** are one per inequality row, bounded :math:`0 \le w \le w_{max}` where
  :math:`w_{max}` exceeds the largest violation the box allows (a finite bound every backend
  accepts). Each level's QP is feasible by construction (:math:`\dot q^*_{k-1}` with
  :math:`w = \max(0, G_k\dot q^*_{k-1} - h_k)` satisfies it), so an "infeasible" report is a
  backend failure and handled as such.
* **Rows that cannot bind are dropped**: a row with :math:`\max_{\dot q \in box} g^T\dot q \le h`
  is redundant given the hard box (exact; most rows of a safe state).
* **Unconstrained first** (``unconstrained_first``, default on): a level's strictly convex QP
  has a unique solution; when the unconstrained minimiser (one n×n linear solve) satisfies every
  inequality it *is* that solution and the backend is not called. ``extras["qp_calls"]`` counts
  the levels that did call it. A level that needed the backend at the previous step goes
  straight to it (its active set usually persists; the answer is the same either way).

Every backend answer is **certified** before use (:mod:`qp_baseline.certificate`, issue 23),
whatever status the backend reported: its slacks set to their minimal value ``max(0, G q̇ − h)``,
the answer must be within ``tolerance`` of every constraint, no worse than the known feasible
point, and its level objective within ``objective_tolerance`` of the lower bound that the
backend's multipliers (or multipliers recovered for the answer) prove — the primal residual, dual
residual and duality gap of qpbenchmark are reported in ``extras["certificates"]``. An answer that
fails is polished (:mod:`qp_baseline.polish`, exact KKT solves of its active set) and certified
again; then retried once with its backend's retry settings (:data:`qp_baseline.backends.BACKENDS`)
and :data:`RETRY_REGULARIZATION`. What remains:

* no usable answer (infeasible, non-finite, worse than the known feasible point): the level is
  **given up** — level 0 → FAILED with zero velocity, a later level → DEGRADED keeping the
  solution of the levels above it, ``extras["levels_dropped"]`` = that level and every level below;
* a usable answer that is not certified: kept, the step DEGRADED and the level counted in
  ``extras["levels_uncertified"]`` (FAILED at level 0). Never silently accepted.

The min-norm level is certified on its distance to the optimum (it only picks the null-space part
of q̇); an uncertified min-norm answer is kept (it meets every level above) and noted in
``extras["min_norm_failure"]``. ``certify = false`` restores the checks before issue 23 (status,
constraints, known feasible point). :attr:`HqpSolver.qp_log` records the level QPs
(:class:`~qp_baseline.level_qp.LevelQp`), e.g. for a qpbenchmark export.
"""

from __future__ import annotations

import contextlib
import math
import os
import re
import sys
import time
import warnings
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np
import qpsolvers
import scipy.sparse as spa

from qp_baseline.backends import BACKENDS, SUPPORTED_SOLVERS
from qp_baseline.cascade_kernels import (
    binds,
    clip_into,
    equality_rows,
    feasible,
    level_objective,
    raise_to,
    zero_feasible,
)
from qp_baseline.cascade_kernels import warm_up as warm_up_kernels
from qp_baseline.certificate import Certificate, Tolerances, certify, certify_dense
from qp_baseline.certificate import warm_up as warm_up_certificate
from qp_baseline.exceptions import InvalidSettings, NoSolutionFound, UnknownSolver
from qp_baseline.level_qp import LevelAnswer, LevelQp
from qp_baseline.polish import polish
from qp_baseline.set_rows import SetRowBuilder
from qp_baseline.time_limits import TimeLimited
from robots import Kinematics, Robot
from tpik.evaluation import TaskEvaluation
from tpik.exceptions import InvalidTaskState
from tpik.hierarchy import Hierarchy
from tpik.limits import Limit, PositionLimit, VelocityLimit, compose_box
from tpik.reference import ControlReference
from tpik.step_result import SolveStatus, StepResult, failed
from tpik.tasks import SetTask, Task


def available_qp_solvers() -> list[str]:
    """Backends usable here: the supported ones (:mod:`qp_baseline.backends`) that qpsolvers has installed."""
    installed = set(qpsolvers.available_solvers)
    return [name for name in SUPPORTED_SOLVERS if name in installed]


RETRY_REGULARIZATION = 1e-7
"""Extra diagonal added to the Hessian on the retry (near-singular Hessians: DAQP, quadprog). Small
enough that the retry's answer still passes the certificate of the original problem (1e-6 shifted
well-conditioned levels by about the certificate's tolerance)."""


def _check_solver(solver: str) -> None:
    if solver not in available_qp_solvers():
        raise UnknownSolver(solver, available_qp_solvers())


@contextlib.contextmanager
def _quiet_stdout(enabled: bool) -> Iterator[None]:
    """Silence the C library's stdout (OSQP prints "Polishing not needed" whatever ``verbose``)."""
    if not enabled:
        yield
        return
    try:
        fd = sys.stdout.fileno()
    except (AttributeError, OSError, ValueError):
        yield
        return
    sys.stdout.flush()
    saved = os.dup(fd)
    try:
        with open(os.devnull, "wb") as devnull:
            os.dup2(devnull.fileno(), fd)
        yield
    finally:
        os.dup2(saved, fd)
        os.close(saved)


def backend_kwargs(solver: str, settings: Mapping[str, Any]) -> dict[str, Any]:
    """Settings as the backend takes them: ProxQP's ``initial_guess`` name becomes its enum.

    Raises:
        InvalidSettings: Unknown ``initial_guess`` name.
    """
    kwargs = dict(settings)
    guess = kwargs.get("initial_guess")
    if BACKENDS[solver].initial_guess_by_name and isinstance(guess, str):
        from proxsuite import proxqp

        names = proxqp.InitialGuess.__members__
        if guess not in names:
            raise InvalidSettings(solver, f"setting 'initial_guess' must be one of {', '.join(names)}, got {guess!r}")
        kwargs["initial_guess"] = names[guess]
    return kwargs


def _solve_quietly(problem: qpsolvers.Problem, solver: str, quiet: bool, **kwargs: Any) -> qpsolvers.Solution:
    """``qpsolvers.solve_problem`` without the failure warnings (failures are reported in StepResult)."""
    if not BACKENDS[solver].warns_on_failure:
        return qpsolvers.solve_problem(problem, solver=solver, **kwargs)
    with warnings.catch_warnings(), _quiet_stdout(quiet):
        warnings.simplefilter("ignore")
        return qpsolvers.solve_problem(problem, solver=solver, **kwargs)


def probe_settings(solver: str, settings: Mapping[str, Any]) -> None:
    """Fail early on a backend setting the backend rejects.

    A two-variable QP is solved with ``settings``; an exception of the backend, or a failure on
    this trivial problem, becomes :class:`InvalidSettings`, naming the setting when the backend's
    message does. PIQP silently ignores unknown names, so those are checked against its settings.

    Raises:
        UnknownSolver: ``solver`` is not available.
        InvalidSettings: A setting is unknown or unusable.
    """
    _check_solver(solver)
    if BACKENDS[solver].ignores_unknown_settings:  # PIQP
        import piqp

        known = {a for a in dir(piqp.DenseSolver().settings) if not a.startswith("_")}
        for key in settings:
            if key not in known:
                raise InvalidSettings(solver, f"unknown setting '{key}'; known: {', '.join(sorted(known))}", key)
    P = np.eye(2)
    G = np.array([[1.0, 1.0]])
    if BACKENDS[solver].sparse:
        problem = qpsolvers.Problem(spa.csc_matrix(P), np.array([-1.0, -1.0]), spa.csc_matrix(G), np.ones(1))
    else:
        problem = qpsolvers.Problem(P, np.array([-1.0, -1.0]), G, np.ones(1))
    try:
        solution = _solve_quietly(problem, solver, BACKENDS[solver].prints, **backend_kwargs(solver, settings))
    except Exception as exc:  # noqa: BLE001 - whatever the backend raises is a settings error here
        bad_key = next((k for k in settings if re.search(rf"\b{re.escape(k)}\b", str(exc))), None)
        named = f"setting '{bad_key}'" if bad_key else f"settings {dict(settings)}"
        raise InvalidSettings(solver, f"{named} rejected by the backend: {exc}", bad_key) from exc
    if not solution.found or solution.x is None or not np.allclose(solution.x, [0.5, 0.5], atol=1e-3):
        raise InvalidSettings(solver, f"settings {dict(settings)} make the backend fail on a trivial QP")


def default_limits(robot: Robot) -> tuple[Limit, ...]:
    r"""HQP's hard box: the robot's velocity limits, then its position limits over one step.

    Composed in this order (:func:`tpik.limits.compose_box`) the box is
    :math:`\max(-v_{max}, (q_{min} - q)/dt) \le \dot q \le \min(v_{max}, (q_{max} - q)/dt)`, the
    position part clipped into :math:`[-v_{max}, v_{max}]` so that it is never empty.
    """
    return (VelocityLimit.from_robot(robot), PositionLimit.from_robot(robot))


@dataclass(frozen=True)
class HqpSettings:
    r"""Options of the cascade itself; every other setting goes to the QP backend.

    Attributes:
        regularization: ε of :math:`\epsilon\|\dot q\|^2` on every task level (unitless, > 0).
        tolerance: Accepted constraint violation of a backend answer [rad/s or m/s]; the
            backend's tolerance (:data:`qp_baseline.backends.BACKENDS`) when None.
        slack_tolerance: A slack above this makes the step DEGRADED; a row within it of its bound
            is reported binding (active set) [task unit / s]. ``max(1e-6, tolerance)`` when None.
        rank_tolerance: Relative singular-value threshold of the null-space bases.
        unconstrained_first: Skip the backend when a level's unconstrained minimiser is feasible.
        min_norm_level: Solve the final min-norm level; the backend's default
            (:data:`qp_baseline.backends.BACKENDS`) when None.
        retry: Retry a failed level once with its backend's retry settings (:data:`qp_baseline.backends.BACKENDS`).
        gain_cap: Cap every task gain at 1/dt in the control reference (:mod:`tpik.reference`;
            the same default as TPIK and mink).
        certify: Judge every backend answer by its certificate (:mod:`qp_baseline.certificate`:
            primal residual, dual residual, duality gap, level objective against the dual bound);
            off: status, constraints and the known feasible point only (the checks before issue 23).
        objective_tolerance: Accepted error of a level's residual norm, relative to 1 + ρ
            (:attr:`~qp_baseline.certificate.Tolerances.level`); ``max(1e-6, tolerance)`` when None.
        warm_start: Start each level's backend from that level's answer at the previous step;
            the backend's default (off for every backend) when None.
        kkt_polish: When a backend answer is not certified, polish it (:func:`qp_baseline.polish.polish`:
            exact KKT solves of the active set the answer identifies) and keep the polished answer if
            it is certified — OSQP's polishing idea, for every backend (one small least squares).
            Not OSQP's own ``polish`` setting, which goes to OSQP.
    """

    regularization: float = 1e-9
    tolerance: float | None = None
    slack_tolerance: float | None = None
    rank_tolerance: float = 1e-9
    unconstrained_first: bool = True
    min_norm_level: bool | None = None
    retry: bool = True
    gain_cap: bool = True
    certify: bool = True
    objective_tolerance: float | None = None
    warm_start: bool | None = None
    kkt_polish: bool = True

    def check(self, solver: str) -> None:
        """Raise :class:`InvalidSettings` naming the first bad value."""
        for key in ("regularization", "slack_tolerance", "rank_tolerance", "tolerance", "objective_tolerance"):
            value = getattr(self, key)
            if value is None and key in ("tolerance", "slack_tolerance", "objective_tolerance"):
                continue
            number = isinstance(value, int | float) and not isinstance(value, bool)
            if not (number and math.isfinite(value) and value > 0):
                raise InvalidSettings(solver, f"setting '{key}' must be a finite number > 0, got {value!r}", key)
        for key in (
            "unconstrained_first",
            "min_norm_level",
            "retry",
            "gain_cap",
            "certify",
            "warm_start",
            "kkt_polish",
        ):
            value = getattr(self, key)
            if not (isinstance(value, bool) or (value is None and key in ("min_norm_level", "warm_start"))):
                raise InvalidSettings(solver, f"setting '{key}' must be true or false, got {value!r}", key)


def split_settings(solver: str, settings: Mapping[str, Any] | None) -> tuple[HqpSettings, dict[str, Any]]:
    """Split one config table into cascade options (:class:`HqpSettings`) and backend arguments.

    Raises:
        InvalidSettings: A cascade option has a bad value.
    """
    own = {f.name for f in fields(HqpSettings)}
    data = dict(settings or {})
    options = HqpSettings(**{k: data.pop(k) for k in list(data) if k in own})
    options.check(solver)
    return options, data


@dataclass
class _Level:
    """One priority level: its equality tasks and their preallocated buffers."""

    name: str
    eq_tasks: tuple[Task, ...]
    eq_slices: tuple[slice, ...]
    J: np.ndarray  # (m_eq, n), preallocated
    r: np.ndarray  # (m_eq,), preallocated


@dataclass
class _Cascade:
    """Running state of one step's cascade: q̇ so far, relaxed bounds, null space, counters."""

    qd: np.ndarray  # q̇ of the levels solved so far
    h_rel: np.ndarray  # set-row bounds relaxed by the solved levels' slacks
    lb: np.ndarray  # hard box (composed limits)
    ub: np.ndarray
    cuts: list[int]  # rows of level k: cuts[k]:cuts[k + 1]
    Z: np.ndarray | None = None  # null-space basis of the solved equality rows; None: identity
    slack: np.ndarray | None = None  # per row, set by the first backend answer
    residuals: dict[str, float] = field(default_factory=dict)
    iterations: dict[str, int] = field(default_factory=dict)
    qp_calls: int = 0
    retries: int = 0
    levels_dropped: int = 0
    levels_uncertified: int = 0
    status: SolveStatus = SolveStatus.OK
    message: str = ""
    min_norm_failure: str = ""

    def add_message(self, name: str, note: str) -> None:
        self.message = f"{self.message}; {note}" if self.message else f"{name}: {note}"


@dataclass
class _LevelProblem:
    """Inputs of one level's solve (see :meth:`HqpSolver._solve_level`)."""

    k: int
    qd: np.ndarray
    Z: np.ndarray | None
    J: np.ndarray
    r: np.ndarray
    G_all: np.ndarray
    h_rel: np.ndarray
    c0: int
    c1: int
    lb: np.ndarray
    ub: np.ndarray
    eps: float
    margin: float
    at_zero: bool = False  # Z = I and qd = 0: the products with qd are spared

    @property
    def d(self) -> int:
        """Number of free variables z."""
        return self.qd.shape[0] if self.Z is None else self.Z.shape[1]


@dataclass
class _QpCall:
    """One QP as :meth:`HqpSolver.solve_qp` poses it, and how its answers are judged."""

    P: np.ndarray
    q: np.ndarray
    G: np.ndarray
    h: np.ndarray
    lb: np.ndarray
    ub: np.ndarray
    x0: np.ndarray  # a feasible point
    f0: float  # objective at x0
    level_value: Callable[[np.ndarray], float] | None = None
    refine: Callable[[np.ndarray], np.ndarray] | None = None
    curvature: np.ndarray | None = None
    modulus: float | None = None
    slacks: int = 0  # number of slack variables (the last entries of x)


@dataclass
class _Trail:
    """What the attempts of one QP left: last backend answer, its certificate, why, a fallback."""

    solution: Any = None
    certificate: Certificate | None = None
    reason: str = ""
    usable: LevelAnswer | None = None


def _minimal_slacks(G_slack: np.ndarray, h_slack: np.ndarray, d: int) -> Callable[[np.ndarray], np.ndarray]:
    """Map x = [z; w] to the same z with its minimal slacks w = max(0, G q̇ − h) (feasible, no worse)."""

    def minimal_slacks(x: np.ndarray) -> np.ndarray:
        out = x.copy()
        out[d:] = np.maximum(G_slack @ x[:d] - h_slack, 0.0)
        return out

    return minimal_slacks


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
        _check_solver(solver)
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
        self._kwargs = backend_kwargs(solver, self.qp_settings)
        self._retry_kwargs = backend_kwargs(solver, {**self.qp_settings, **backend.retry})
        self._resolve_defaults(solver)
        warm_up_certificate()  # the compiled certificate and kernels are loaded now, not at the first step
        warm_up_kernels(robot.nq)
        self.qp_log: list[LevelQp] | None = None
        """When a list, every backend-solved level QP is appended to it (:class:`LevelQp`)."""
        self._previous: dict[int, np.ndarray] = {}  # level → its q̇ answer at the previous step
        self._certificates: dict[int, Certificate] = {}  # this step's, per level
        self._sparse = backend.sparse
        self._quiet = backend.prints
        n = robot.nq
        self._eye = np.eye(n)
        self._eps_eye = self.options.regularization * np.eye(n)
        self._zeros = np.zeros(n)
        self._hierarchy: Hierarchy | None = None
        self._levels: list[_Level] = []
        self._first_eq = 0
        self._set_tasks: tuple[SetTask, ...] = ()
        self._set_level: tuple[int, ...] = ()
        self._set_names: tuple[str, ...] = ()
        self._set_level_of = np.zeros(0, dtype=int)
        self._rows = SetRowBuilder((), n, self.reference)
        self._no_rows = np.zeros((0, n))
        self._no_bounds = np.zeros(0)
        self._no_owner = np.zeros(0, dtype=int)
        self._G, self._h, self._owner = self._no_rows, self._no_bounds, self._no_owner
        self._backend_time = 0.0
        # Levels whose unconstrained minimiser was infeasible at the previous step: their active
        # set usually persists, so they go straight to the backend (same unique solution).
        self._needed_backend: dict[int, bool] = {}
        self._curvatures: dict[tuple[int, int, float], np.ndarray] = {}  # see _curvature

    def _resolve_defaults(self, solver: str) -> None:
        """Tolerances, min-norm level and warm start: the options, or the backend's defaults."""
        self.tolerance = float(self.options.tolerance or BACKENDS[solver].tolerance)
        self.slack_tolerance = float(self.options.slack_tolerance or max(1e-6, self.tolerance))
        self.slack_margin = 0.1 * self.tolerance
        mnl = self.options.min_norm_level
        self.min_norm_level = BACKENDS[solver].min_norm_level if mnl is None else mnl
        self.objective_tolerance = float(self.options.objective_tolerance or max(1e-6, self.tolerance))
        self.certificate_tolerances = Tolerances(
            primal=self.tolerance, level=self.objective_tolerance, active=max(1e-6, self.tolerance)
        )
        ws = self.options.warm_start
        self.warm_start = BACKENDS[solver].warm_start if ws is None else ws

    def __repr__(self) -> str:
        return f"HqpSolver(name={self.name!r}, solver={self.solver!r}, settings={self.qp_settings})"

    # ------------------------------------------------------------------ structure
    def _prepare(self, hierarchy: Hierarchy) -> None:
        """Allocate the level buffers once per hierarchy object."""
        if hierarchy is self._hierarchy:
            return
        self._needed_backend = {}
        self._previous = {}
        n = self.robot.nq
        levels: list[_Level] = []
        set_tasks: list[SetTask] = []
        set_level: list[int] = []
        for k, level in enumerate(hierarchy.levels):
            eq = tuple(t for t in level.tasks if not isinstance(t, SetTask))
            slices, start = [], 0
            for task in eq:
                slices.append(slice(start, start + task.dim))
                start += task.dim
            levels.append(_Level(level.name, eq, tuple(slices), np.zeros((start, n)), np.zeros(start)))
            for task in level.tasks:
                if isinstance(task, SetTask):
                    set_tasks.append(task)
                    set_level.append(k)
        self._levels = levels
        # One evaluation pass over every task (tpik.evaluation): equality tasks level after
        # level, then the set tasks in the order their rows are stacked.
        eq_tasks: list[Task] = [t for lv in levels for t in lv.eq_tasks]
        self._evaluation = TaskEvaluation([*eq_tasks, *set_tasks], self.robot)
        ptr = self._evaluation.eq_ptr
        self._eq_J, self._eq_r = np.zeros((int(ptr[-1]), n)), np.zeros(int(ptr[-1]))
        self._eq_spans: list[tuple[_Level, int, int]] = []
        e = 0
        for lv in levels:
            if lv.eq_tasks:
                self._eq_spans.append((lv, int(ptr[e]), int(ptr[e + len(lv.eq_tasks)])))
            e += len(lv.eq_tasks)
        self._first_eq = next((k for k, lv in enumerate(levels) if lv.r.size), len(levels))
        self._set_tasks = tuple(set_tasks)
        self._set_level = tuple(set_level)
        self._set_names = tuple(t.name for t in set_tasks)
        self._set_level_of = np.array(set_level, dtype=np.int64)  # level of each set task
        self._cuts = np.zeros(len(levels) + 1, dtype=np.int64)
        self._rows = SetRowBuilder(self._set_tasks, n, self.reference)
        self._hierarchy = hierarchy

    def _box(self, q: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
        r"""Hard bounds :math:`\underline v \le \dot q \le \overline v` [rad/s]: the composed :attr:`limits`."""
        return compose_box(self.limits, q, dt)

    def _evaluate(self, kin: Kinematics, dt: float, lb: np.ndarray, ub: np.ndarray) -> list[int]:
        """Evaluate every task once: equality tasks into their level buffers, set tasks into rows.

        One pass of the shared task evaluation (:mod:`tpik.evaluation`: σ̃, σ̇_d, J per row) for
        all tasks; the CLIK references (eq. 2) in one compiled call
        (:func:`~qp_baseline.cascade_kernels.equality_rows`). The set rows that can bind (a row
        that cannot reach its bound inside the hard box is redundant and dropped,
        :meth:`SetRowBuilder.binding`) are stored compacted in ``self._G``, ``self._h`` (bounds),
        ``self._owner`` (index into ``self._set_tasks``), level after level: views of the row
        builder's buffers, valid for this step.

        Returns:
            ``cuts``: the rows of level k are ``cuts[k]:cuts[k + 1]``.
        """
        ev = self._evaluation
        ev.evaluate(kin)
        J, r = self._eq_J, self._eq_r
        if not equality_rows(ev.eq_out, ev.eq_in, ev.eq_ptr, float(dt), self.reference.gain_cap, J, r):
            raise InvalidTaskState(f"{self.name}: non-finite equality task Jacobian or reference")
        for lv, a, b in self._eq_spans:
            lv.J[...] = J[a:b]
            lv.r[...] = r[a:b]
        self._G, self._h, self._owner = self._rows.binding(ev, dt, lb, ub, self._set_level_of, self._cuts)
        return self._cuts.tolist()  # type: ignore[no-any-return]

    # ------------------------------------------------------------------ solve
    def solve(self, hierarchy: Hierarchy, kin: Kinematics, dt: float) -> StepResult:
        """One control step of the cascade.

        Args:
            hierarchy: The shared hierarchy (only read).
            kin: Kinematics snapshot at the current configuration.
            dt: Control period [s].

        Returns:
            OK; DEGRADED (a slack above ``slack_tolerance``, or a lower level given up); or FAILED
            with zero velocity. ``build_time_s`` covers task evaluation and problem assembly,
            ``solve_time_s`` the backend calls and the unconstrained linear solves. ``extras``:
            ``slacks`` {level: {task: slack}}, ``residuals`` {level: ‖J q̇ − r‖}, ``qp_calls``,
            ``iterations`` {level: backend iterations, where reported}, ``retries``,
            ``levels_dropped`` (task levels given up: the failed one and every level below it),
            ``levels_uncertified`` (levels whose answer was kept without a certificate),
            ``certificates`` {level or ``"min_norm"``: :class:`~qp_baseline.certificate.Certificate`
            of each backend-solved level}, ``min_norm_failure``.
        """
        if not (math.isfinite(dt) and dt > 0.0):
            return failed(self.robot.nq, f"dt must be finite and > 0, got {dt}")
        t_start = time.perf_counter()
        if self.budget is not None:
            self.budget.start()
        self._backend_time = 0.0
        self._certificates = {}
        self._prepare(hierarchy)
        lb, ub = self._box(kin.q, dt)
        cuts = self._evaluate(kin, dt, lb, ub)  # a task error (tpik.TpikError) propagates, as in every solver
        run = _Cascade(self._zeros.copy(), self._h.copy(), lb, ub, cuts)
        result = self._run_levels(run, t_start)
        if result is None:
            result = self._report(run, t_start)
        for limit in self.limits:
            limit.observe(result.qdot)
        return result

    def _first_level(self, run: _Cascade) -> int:
        """Where the cascade starts: after leading levels of set tasks only that q̇ = 0 solves.

        Zero is their regularised optimum when it is feasible: inside the box and every such row
        has h ≥ 0 (the fast path of ``unconstrained_first``).
        """
        if not self.options.unconstrained_first:
            return 0
        first_eq = self._first_eq
        c_pre = run.cuts[first_eq]
        if first_eq and zero_feasible(run.lb, run.ub, run.h_rel[:c_pre]):
            return first_eq
        return 0

    def _level_rows(self, k: int, run: _Cascade) -> tuple[np.ndarray, np.ndarray, int, int, float] | None:
        """(J, r, first row, end row, margin) of level ``k``; None: the cascade ends before it.

        The min-norm level (k = number of task levels) is min ‖q̇‖² under all rows, solved only
        after a backend answer (without one q̇ is already the exact ε-regularised minimum-norm
        solution). Its optimum sits on the constraints of the levels above: a margin δ gives the
        feasible set an interior (ProxQP reports "infeasible" without it).
        """
        if k < len(self._levels):
            lv = self._levels[k]
            return lv.J, lv.r, run.cuts[k], run.cuts[k + 1], 0.0
        if self.min_norm_level and run.qp_calls:
            return self._eye, self._zeros, run.cuts[k], run.cuts[k], self.slack_margin
        return None

    def _run_levels(self, run: _Cascade, t_start: float) -> StepResult | None:
        """Solve the levels in priority order into ``run``; a FAILED result when level 0 fails."""
        n_levels = len(self._levels)
        eps = self.options.regularization
        for k in range(self._first_level(run), n_levels + 1):
            rows = self._level_rows(k, run)
            if rows is None:
                break
            J, r, c0, c1, margin = rows
            d = self.robot.nq if run.Z is None else run.Z.shape[1]
            if d == 0 or (r.size == 0 and c0 == c1):
                continue
            try:
                qd, used, its, retried, doubt = self._solve_level(
                    k, run.qd, run.Z, J, r, self._G, run.h_rel, c0, c1, run.lb, run.ub, eps, margin
                )
            except NoSolutionFound as exc:
                if k == 0:
                    return self._failed(f"{self.name}: {exc}", t_start, k)
                self._give_up(run, k, exc)
                break
            run.qd = qd
            if doubt:
                if k == 0:
                    return self._failed(f"{self.name}: priority level 0: answer not certified: {doubt}", t_start, k)
                self._note_doubt(run, k, doubt)
            self._after_level(run, k, J, r, c0, c1, used, its, retried)
        return None

    def _give_up(self, run: _Cascade, k: int, exc: NoSolutionFound) -> None:
        """Level ``k`` > 0 had no usable answer: keep the solution of the levels above it."""
        n_levels = len(self._levels)
        if k == n_levels:
            run.min_norm_failure = str(exc)  # it only picks among equally good answers
            return
        run.status = SolveStatus.DEGRADED
        run.levels_dropped = n_levels - k
        run.message = f"{self.name}: {exc}; kept the solution of the levels above ({run.levels_dropped} dropped)"

    def _note_doubt(self, run: _Cascade, k: int, doubt: str) -> None:
        """Level ``k`` > 0 kept an uncertified answer: DEGRADED (the min-norm level: noted only)."""
        if k == len(self._levels):
            run.min_norm_failure = f"answer not certified: {doubt}"  # kept: it meets every level above
            return
        run.status = SolveStatus.DEGRADED
        run.levels_uncertified += 1
        run.add_message(self.name, f"priority level {k} ({self._levels[k].name}): answer not certified: {doubt}")

    def _after_level(
        self,
        run: _Cascade,
        k: int,
        J: np.ndarray,
        r: np.ndarray,
        c0: int,
        c1: int,
        used: int,
        its: int | None,
        retried: int,
    ) -> None:
        """Book-keeping after level ``k``: counters, relaxed rows, residual, the next null space."""
        run.qp_calls += used
        run.retries += retried
        if its is not None:
            run.iterations[self._level_name(k)] = its
        if used and c1 > c0:
            # This level's slack at its own optimum relaxes its rows for every later level; a
            # relaxed row sits on the best value reachable, so it gets a margin δ: without it
            # the later feasible set has no interior and quadprog and the interior-point
            # backends report it infeasible.
            w = self._G[c0:c1] @ run.qd
            w -= run.h_rel[c0:c1]
            np.maximum(w, 0.0, out=w)
            if run.slack is None:
                run.slack = np.zeros(run.h_rel.shape[0])
            run.slack[c0:c1] = w
            run.h_rel[c0:c1] += w + self.slack_margin * (w > 0.0)
        n_levels = len(self._levels)
        if r.size and k < n_levels:
            res = J @ run.qd - r
            run.residuals[self._levels[k].name] = math.sqrt(float(res @ res))  # np.linalg.norm's own sum
            if k + 1 < n_levels or (self.min_norm_level and run.qp_calls):
                run.Z = self._null_space(J, run.Z)

    def _set_task_report(self, run: _Cascade) -> tuple[dict[str, dict[str, float]], list[str], list[str]]:
        """Per level the largest slack of each set task; the binding tasks; the relaxed ones.

        A task binds when one of its rows is within ``slack_tolerance`` of its relaxed bound at
        the final q̇, or was relaxed by more than that; it is relaxed by its rows' largest slack.
        """
        s_tol = self.slack_tolerance
        slacks: dict[str, dict[str, float]] = {}
        active: list[str] = []
        relaxed: list[str] = []
        if not run.h_rel.size:
            return slacks, active, relaxed
        # Slacks only come from backend answers: without a backend call they are all zero.
        Gq, h = (self._G @ run.qd).tolist(), run.h_rel.tolist()
        slack = run.slack.tolist() if run.slack is not None else [0.0] * len(h)
        names, level_of = self._set_names, self._set_level
        by_level: dict[int, dict[str, float]] = {}
        for row, task in enumerate(self._owner.tolist()):
            name, w = names[task], slack[row]
            per_task = by_level.setdefault(level_of[task], {})
            per_task[name] = max(per_task.get(name, 0.0), w)
            if (Gq[row] >= h[row] - s_tol or w > s_tol) and name not in active:
                active.append(name)
            if w > s_tol and name not in relaxed:
                relaxed.append(name)
        for k, per_task in by_level.items():
            slacks[self._levels[k].name] = per_task
        return slacks, active, relaxed

    def _report(self, run: _Cascade, t_start: float) -> StepResult:
        """The step's :class:`StepResult` from the finished cascade (q̇ clipped into the box)."""
        qd = run.qd
        clip_into(qd, run.lb, run.ub)
        slacks, active, relaxed = self._set_task_report(run)
        if relaxed:
            run.add_message(self.name, f"set tasks relaxed (slack > {self.slack_tolerance:g}): {', '.join(relaxed)}")
            run.status = SolveStatus.DEGRADED
        total = time.perf_counter() - t_start
        return StepResult(
            qd,
            run.status,
            tuple(active),
            build_time_s=total - self._backend_time,
            solve_time_s=self._backend_time,
            message=run.message,
            extras={
                "slacks": slacks,
                "residuals": run.residuals,
                "qp_calls": run.qp_calls,
                "iterations": run.iterations,
                "retries": run.retries,
                "min_norm_failure": run.min_norm_failure,
                "levels_dropped": run.levels_dropped,
                "levels_uncertified": run.levels_uncertified,
                "certificates": {self._level_name(k): c for k, c in self._certificates.items()},
            },
        )

    def _level_name(self, k: int) -> str:
        return self._levels[k].name if k < len(self._levels) else "min_norm"

    def _failed(self, message: str, t_start: float, level: int) -> StepResult:
        res = failed(
            self.robot.nq,
            message,
            level=level,
            levels_dropped=len(self._levels),
            certificates={self._level_name(k): c for k, c in self._certificates.items()},
        )
        res.solve_time_s = self._backend_time
        res.build_time_s = time.perf_counter() - t_start - self._backend_time
        return res

    def _null_space(self, J: np.ndarray, Z: np.ndarray | None) -> np.ndarray:
        """Orthonormal basis of {Z z : J Z z = 0} (Z = I when None). Shape (n, d')."""
        M = J if Z is None else J @ Z
        _, s, Vt = np.linalg.svd(M, full_matrices=True)
        top = float(s[0]) if s.size else 0.0
        rank = int(np.count_nonzero(s > self.options.rank_tolerance * max(1.0, top)))
        basis = Vt[rank:].T
        return basis if Z is None else Z @ basis

    # ------------------------------------------------------------------ one level
    def _solve_level(
        self,
        k: int,
        qd: np.ndarray,
        Z: np.ndarray | None,
        J: np.ndarray,
        r: np.ndarray,
        G_all: np.ndarray,
        h_rel: np.ndarray,
        c0: int,
        c1: int,
        lb: np.ndarray,
        ub: np.ndarray,
        eps: float,
        margin: float = 0.0,
    ) -> tuple[np.ndarray, int, int | None, int, str]:
        """Solve level ``k`` for q̇ = qd + Z z.

        Rows ``:c0`` of ``G_all``/``h_rel`` are the earlier levels' (already relaxed), rows
        ``c0:c1`` this level's (with slack). ``h_rel[:c0]`` is raised in place by any violation
        within tolerance of the accepted answer, so later levels stay feasible by construction.
        ``margin`` relaxes every row of the QP (min-norm level only).

        Returns:
            (q̇, 1 if the backend was called else 0, backend iterations, 1 if retried else 0, why
            the answer is not certified — empty when it is, or when no backend was called).

        Raises:
            NoSolutionFound: Neither attempt gave a usable answer (feasible, no worse than the
                known feasible point).
        """
        lp = _LevelProblem(k, qd, Z, J, r, G_all, h_rel, c0, c1, lb, ub, eps, margin)
        lp.at_zero = Z is None and not qd.any()  # start of the cascade: spare the products with qd
        Pz, qz = self._level_cost(lp)
        if self.options.unconstrained_first and not self._needed_backend.get(k, False):
            cand = self._unconstrained(lp, Pz, qz)
            if cand is not None:
                self._previous[k] = cand
                return cand, 0, None, 0, ""
        if Pz is None or qz is None:
            Pz = np.eye(lp.d) * eps
            qz = eps * (qd if Z is None else Z.T @ qd)
        call = self._level_qp(lp, Pz, qz)
        answer = self._backend_answer(lp, call)
        cand = self._accept_level(lp, answer.x)
        doubt = "" if answer.certified else ((answer.certificate.reason if answer.certificate else "") or "not checked")
        return cand, 1, backend_iterations(answer.solution), answer.retried, doubt

    def _backend_answer(self, lp: _LevelProblem, call: _QpCall) -> LevelAnswer:
        """The level's QP through :meth:`solve_qp` (warm start, :attr:`qp_log`, certificate kept).

        Raises:
            NoSolutionFound: As :meth:`solve_qp`.
        """
        k, qd, Z = lp.k, lp.qd, lp.Z
        start = None
        if self.warm_start and k in self._previous:
            start = self._warm_start_point(
                self._previous[k], qd, Z, lp.at_zero, lp.G_all[lp.c0 : lp.c1], lp.h_rel[lp.c0 : lp.c1], call.lb, call.ub
            )
        try:
            answer = self.solve_qp(
                call.P,
                call.q,
                call.G,
                call.h,
                call.lb,
                call.ub,
                call.x0,
                call.f0,
                k,
                call.level_value,
                start,
                call.refine,
                call.curvature,
                call.modulus,
            )
        except NoSolutionFound as exc:
            self._record(k, call, None, exc.certificate)
            raise
        self._record(k, call, answer.x, answer.certificate)
        if answer.certificate is not None:
            self._certificates[k] = answer.certificate
        return answer

    def _level_cost(self, lp: _LevelProblem) -> tuple[np.ndarray | None, np.ndarray | None]:
        r"""Cost of the level in z, :math:`P_z = (JZ)^T JZ + \epsilon I` and :math:`q_z`.

        (None, None) without equality rows (P = εI, built by the caller when needed).
        """
        J, r, qd, Z, eps = lp.J, lp.r, lp.qd, lp.Z, lp.eps
        if not r.size:
            return None, None
        JZ = J if Z is None else J @ Z
        d = JZ.shape[1]
        Pz = JZ.T @ JZ
        Pz += self._eps_eye if d == qd.shape[0] and eps == self.options.regularization else eps * np.eye(d)
        if lp.at_zero:
            qz = -(JZ.T @ r)
        else:
            qz = JZ.T @ (J @ qd - r)
            if eps:
                qz += eps * (qd if Z is None else Z.T @ qd)
        return Pz, qz

    def _unconstrained(self, lp: _LevelProblem, Pz: np.ndarray | None, qz: np.ndarray | None) -> np.ndarray | None:
        """The level's unconstrained minimiser when it meets every row and the box, else None."""
        qd, Z = lp.qd, lp.Z
        if Pz is not None and qz is not None:
            t0 = time.perf_counter()
            z = np.linalg.solve(Pz, -qz)
            self._backend_time += time.perf_counter() - t0
            cand = z if lp.at_zero else (qd + z if Z is None else qd + Z @ z)
        else:
            # Pz = εI: the minimiser is qd without its component in span(Z).
            cand = self._zeros.copy() if Z is None else qd - Z @ (Z.T @ qd)
        c1 = lp.c1
        Gc = lp.G_all[:c1] @ cand if c1 else self._no_bounds
        return cand if feasible(cand, lp.lb, lp.ub, Gc, lp.h_rel[:c1]) else None

    def _level_qp(self, lp: _LevelProblem, Pz: np.ndarray, qz: np.ndarray) -> _QpCall:
        """The level's QP in x = [z; w]: earlier rows, this level's rows with slack w, the box."""
        G_rows, h, own0, z_lb, z_ub = self._level_rows_in_z(lp)
        if lp.margin:
            h = h + lp.margin
        d, m = lp.d, lp.c1 - lp.c0
        if m == 0:  # no slack variable: x = z
            call = _QpCall(Pz, qz, G_rows, h, z_lb, z_ub, np.zeros(d), 0.0)
        else:
            G_own, h_own = lp.G_all[lp.c0 : lp.c1], lp.h_rel[lp.c0 : lp.c1]
            G = np.zeros((G_rows.shape[0], d + m))
            G[:, :d] = G_rows
            G[own0 : own0 + m, d:] = -np.eye(m)
            violation = np.maximum(G_own @ lp.qd - h_own, 0.0)  # slack of the known feasible point
            reach = G_own @ (0.5 * (lp.ub + lp.lb)) + np.abs(G_own) @ (0.5 * (lp.ub - lp.lb))
            x_lb = np.concatenate([z_lb, np.zeros(m)])
            x_ub = np.concatenate([z_ub, np.maximum(reach - h_own, violation) + 1.0])
            P = np.zeros((d + m, d + m))
            P[:d, :d] = Pz
            P.flat[d * (d + m) + d :: d + m + 1] = 1.0
            x0 = np.concatenate([np.zeros(d), violation])
            f0 = 0.5 * float(violation @ violation)
            call = _QpCall(P, np.concatenate([qz, np.zeros(m)]), G, h, x_lb, x_ub, x0, f0)
            call.refine = _minimal_slacks(G[own0 : own0 + m, :d], h[own0 : own0 + m], d)
        call.slacks = m
        eps = lp.eps
        # P ⪰ diag(curvature): (JZ)ᵀJZ + εI ⪰ εI (JZ = Z, orthonormal, on the min-norm level), I on slacks.
        bend = 1.0 + eps if lp.J is self._eye else eps
        call.curvature = self._curvature(d, m, bend)
        # Task levels are judged on their objective; the min-norm level (P = (1 + ε)I) on its
        # answer itself: it only picks the null-space part of q̇.
        if lp.k == len(self._levels):
            call.modulus = 1.0 + eps
        else:
            call.level_value = self._level_value(lp, call)
        return call

    def _curvature(self, d: int, m: int, bend: float) -> np.ndarray:
        """``bend`` on the d variables z, 1 on the m slacks (cached per shape; read, never written)."""
        key = (d, m, bend)
        curvature = self._curvatures.get(key)
        if curvature is None:
            curvature = np.concatenate([np.full(d, bend), np.ones(m)])
            self._curvatures[key] = curvature
        return curvature

    def _level_rows_in_z(self, lp: _LevelProblem) -> tuple[np.ndarray, np.ndarray, int, np.ndarray, np.ndarray]:
        """Rows on z of the earlier and this level's set rows (and the box when Z ≠ I), z bounds.

        Returns:
            (G rows, h, index of this level's first row, z lower, z upper).
        """
        qd, Z, G_all, h_rel, c0, c1, lb, ub = lp.qd, lp.Z, lp.G_all, lp.h_rel, lp.c0, lp.c1, lp.lb, lp.ub
        if lp.at_zero:
            return G_all[:c1], h_rel[:c1], c0, lb, ub
        if Z is None:
            return G_all[:c1], h_rel[:c1] - G_all[:c1] @ qd, c0, lb - qd, ub - qd
        d = lp.d
        radius = float(np.linalg.norm(ub - lb)) + 1.0  # ‖z‖ = ‖Z z‖ ≤ diameter of the box
        # The box as rows on z; a joint the earlier equality rows fix entirely gives a zero
        # row "0 ≤ 0" that some backends take for an infeasibility: drop those.
        box_G, box_h = np.vstack([Z, -Z]), np.concatenate([ub - qd, qd - lb])
        live = np.abs(box_G).max(axis=1) > 1e-12
        # Likewise an earlier level's row whose Jacobian lies in the row space of the eliminated
        # equality rows (a wall on the EE under an EE position task): ≈ 0·z ≤ h holds for every
        # z (it holds at z = 0 by construction) and only makes the dual ill-posed (OSQP ran to
        # its iteration limit on such min-norm levels): drop those too.
        GZ = G_all[:c1] @ Z
        h_z = h_rel[:c1] - G_all[:c1] @ qd
        alive = np.abs(GZ[:c0]).max(axis=1, initial=0.0) > 1e-12
        own0 = int(alive.sum())
        G_rows = np.vstack([GZ[:c0][alive], GZ[c0:], box_G[live]])
        h = np.concatenate([h_z[:c0][alive], h_z[c0:], box_h[live]])
        return G_rows, h, own0, np.full(d, -radius), np.full(d, radius)

    def _level_value(self, lp: _LevelProblem, call: _QpCall) -> Callable[[np.ndarray], float]:
        r"""½(‖J q̇ − r‖² + ‖w‖²) of an answer x = [z; w].

        It is :math:`f(x) + \tfrac12\|J q_d - r\|^2 + \tfrac12\epsilon\|q_d\|^2 - \tfrac12\epsilon\|\dot q(x)\|^2`
        (J = I, r = 0 on the min-norm level: ½‖q̇‖²); compiled when Z = I
        (:func:`~qp_baseline.cascade_kernels.level_objective`).
        """
        qd, Z, d, eps, at_zero = lp.qd, lp.Z, lp.d, lp.eps, lp.at_zero
        P, q_vec = call.P, call.q
        if at_zero:  # q_d = 0: J q_d − r = −r
            offset = 0.5 * float(lp.r @ lp.r) if lp.r.size else 0.0
        else:
            res0 = (lp.J @ qd - lp.r) if lp.r.size else self._no_bounds
            offset = 0.5 * float(res0 @ res0 + eps * (qd @ qd))
        if Z is None:
            return lambda x: level_objective(P, q_vec, x, qd, at_zero, offset, eps)  # type: ignore[no-any-return]

        def level_value(x: np.ndarray) -> float:
            qdot = x[:d] if at_zero else (qd + x[:d] if Z is None else qd + Z @ x[:d])
            return float(x @ (0.5 * (P @ x) + q_vec)) + offset - 0.5 * eps * float(qdot @ qdot)

        return level_value

    def _accept_level(self, lp: _LevelProblem, x: np.ndarray) -> np.ndarray:
        """q̇ of the accepted answer, clipped into the box; rows and previous-step state updated."""
        qd, Z, lb, ub, c0, c1 = lp.qd, lp.Z, lp.lb, lp.ub, lp.c0, lp.c1
        d = lp.d
        cand = x[:d].copy() if lp.at_zero else (qd + x[:d] if Z is None else qd + Z @ x[:d])
        clip_into(cand, lb, ub)
        # Next step, go straight to the backend only if a constraint binds now.
        Gc = lp.G_all[:c1] @ cand
        self._needed_backend[lp.k] = binds(cand, lb, ub, Gc, lp.h_rel[:c1], self.tolerance)
        if c0:
            # Absorb violations within tolerance, so later levels stay feasible by construction.
            raise_to(lp.h_rel[:c0], Gc if c0 == c1 else lp.G_all[:c0] @ cand)
        self._previous[lp.k] = cand
        return cand

    @staticmethod
    def _warm_start_point(
        previous: np.ndarray,
        qd: np.ndarray,
        Z: np.ndarray | None,
        at_zero: bool,
        G_own: np.ndarray,
        h_own: np.ndarray,
        x_lb: np.ndarray,
        x_ub: np.ndarray,
    ) -> np.ndarray:
        """The level's previous-step answer ``previous`` (q̇) in this step's variables x = [z; w], clipped."""
        if at_zero:
            z = previous.copy()
        else:
            z = previous - qd if Z is None else Z.T @ (previous - qd)
        if h_own.size:
            qdot = z if at_zero else (qd + z if Z is None else qd + Z @ z)
            z = np.concatenate([z, np.maximum(G_own @ qdot - h_own, 0.0)])
        return np.clip(z, x_lb, x_ub)

    def _record(self, k: int, call: _QpCall, x: np.ndarray | None, certificate: Certificate | None) -> None:
        """Append the level QP to :attr:`qp_log` when it is a list (copies: the buffers are reused)."""
        if self.qp_log is None:
            return
        offset = None
        P, q, x0 = call.P, call.q, call.x0
        if call.level_value is not None:
            probe = x if x is not None else x0
            offset = call.level_value(probe) - float(probe @ (0.5 * (P @ probe) + q))
        self.qp_log.append(
            LevelQp(
                k,
                P.copy(),
                q.copy(),
                call.G.copy(),
                call.h.copy(),
                call.lb.copy(),
                call.ub.copy(),
                x0.copy(),
                None if x is None else x.copy(),
                certificate,
                offset,
                call.slacks,
            )
        )

    # ------------------------------------------------------------------ one checked QP
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
        r"""Solve :math:`\min \tfrac12 x^TPx + q^Tx` s.t. :math:`Gx \le h,\ lb \le x \le ub`, checked.

        With ``certify`` on (default), every answer is judged by its certificate
        (:func:`qp_baseline.certificate.certify` with the backend's multipliers, or recovered
        ones): primal residual within ``tolerance``, objective no worse than at the known
        feasible point ``x0``, and within ``objective_tolerance`` of the dual bound — in the
        level's residual norm when ``level_value`` is given. The backend's own status does not
        decide: a certified answer is right whatever the backend reported, an uncertified
        "solved" one is not. A failed certificate is retried once with its backend's retry settings
        (:data:`qp_baseline.backends.BACKENDS`),
        :data:`RETRY_REGULARIZATION` added to the diagonal of P (the answer is still certified
        against the original P) and ``x0`` as warm start (when ``retry`` is on). If no answer is
        certified, the first *usable* one (feasible within ``tolerance``, no worse than ``x0``)
        is returned with ``certified=False``: the caller reports the level. With ``certify``
        off, an answer is accepted on the backend's status, the constraints and ``x0`` alone.

        Args:
            P: Positive definite cost matrix. Shape (d, d).
            q: Cost vector. Shape (d,).
            G: Inequality matrix, or None. Shape (m, d).
            h: Inequality bounds, or None. Shape (m,).
            lb: Lower bounds of x (finite). Shape (d,).
            ub: Upper bounds of x (finite). Shape (d,).
            x0: A feasible point. Shape (d,).
            f0: Objective at ``x0`` (computed when None).
            level: Priority level reported by :class:`NoSolutionFound`.
            level_value: ½-scaled level objective of an answer (see
                :attr:`~qp_baseline.certificate.Tolerances.level`), None for a plain QP.
            initvals: Warm start of the first attempt (backends that take one: OSQP, ProxQP).
            refine: Exact map applied to an answer before it is judged (the cascade sets the
                slacks of the level's rows to their minimal value ``max(0, G q̇ − h)``).
            curvature: :math:`c` with :math:`P \succeq \mathrm{diag}(c)`, sharpening the certificate's
                bound (see :func:`~qp_baseline.certificate.certify`).
            modulus: :math:`\mu` with :math:`P \succeq \mu I` when the answer itself must be within
                tolerance of the optimum (the min-norm level), not only its objective.

        Returns:
            :class:`~qp_baseline.level_qp.LevelAnswer`.

        Raises:
            NoSolutionFound: No attempt gave a usable answer (``solution`` holds the last answer,
                ``certificate`` its certificate).
        """
        if G is None or h is None:
            G, h = np.zeros((0, q.shape[0])), np.zeros(0)
        if f0 is None:
            f0 = float(x0 @ (0.5 * (P @ x0) + q))
        call = _QpCall(P, q, G, h, lb, ub, x0, f0, level_value, refine, curvature, modulus)
        return self._solve_call(call, level, initvals)

    def _solve_call(self, call: _QpCall, level: int, initvals: np.ndarray | None) -> LevelAnswer:
        """:meth:`solve_qp` of a bundled problem: the attempts in order, the first certified answer."""
        attempts: list[tuple[dict[str, Any], float, np.ndarray | None]] = [(self._kwargs, 0.0, initvals)]
        if self.options.retry:
            attempts.append((self._retry_kwargs, RETRY_REGULARIZATION, call.x0))
        trail = _Trail()
        for attempt, (kwargs, extra_reg, start) in enumerate(attempts):
            if attempt and trail.usable is not None:
                start = trail.usable.x  # the retry starts from the first attempt's usable answer, when there is one
            answer = self._attempt(call, attempt, kwargs, extra_reg, start, trail)
            if answer is not None:
                return answer
        if trail.usable is not None:
            return trail.usable
        raise NoSolutionFound(level, trail.solution, trail.reason, trail.certificate)

    def _attempt(
        self,
        call: _QpCall,
        attempt: int,
        kwargs: Mapping[str, Any],
        extra_reg: float,
        start: np.ndarray | None,
        trail: _Trail,
    ) -> LevelAnswer | None:
        """One backend call and its judgement; None (and why, in ``trail``) when not accepted."""
        P_try = call.P
        if extra_reg:
            P_try = call.P.copy()
            P_try.flat[:: call.q.shape[0] + 1] += extra_reg
        try:
            solution = self._call_backend(P_try, call.q, call.G, call.h, call.lb, call.ub, start, kwargs)
        except Exception as exc:  # noqa: BLE001 - a backend error is a failure of this QP
            trail.solution, trail.reason = None, f"{self.solver} raised {type(exc).__name__}: {exc}"
            return None
        trail.solution = solution
        x = solution.x
        if x is None or (not solution.found and not self.options.certify):
            trail.reason = f"{self.solver} reported no solution"
            return None
        x = np.asarray(x, dtype=float)
        if x.shape != call.q.shape or not np.isfinite(x).all():
            trail.reason = f"{self.solver} returned a non-finite or misshaped solution"
            return None
        if not self.options.certify:
            return self._accept_on_status(call, x, solution, attempt, trail)
        if call.refine is not None:
            x = call.refine(x)
        return self._certified_answer(call, x, solution, attempt, trail)

    def _accept_on_status(
        self, call: _QpCall, x: np.ndarray, solution: qpsolvers.Solution, attempt: int, trail: _Trail
    ) -> LevelAnswer | None:
        """The checks of ``certify = false``: constraints within tolerance, no worse than x0."""
        tol, f0 = self.tolerance, call.f0
        viol = max((call.lb - x).max(), (x - call.ub).max(), (call.G @ x - call.h).max() if call.h.size else -math.inf)
        if viol > tol:
            trail.reason = f"{self.solver} answer violates its constraints by {viol:.3g} (tolerance {tol:g})"
            return None
        f = float(x @ (0.5 * (call.P @ x) + call.q))
        if f > f0 + tol * (1.0 + abs(f0)):
            trail.reason = f"{self.solver} answer is worse than a known feasible point ({f:.6g} > {f0:.6g})"
            return None
        return LevelAnswer(x, solution, attempt, None, True)

    def _certified_answer(
        self, call: _QpCall, x: np.ndarray, solution: qpsolvers.Solution, attempt: int, trail: _Trail
    ) -> LevelAnswer | None:
        """Judge ``x``: the backend's multipliers, then the KKT polish, then recovered multipliers.

        An answer that is not certified but usable (feasible within tolerance, no worse than x0)
        is kept in ``trail`` as the fallback.
        """
        tol, f0 = self.tolerance, call.f0
        z, z_box = getattr(solution, "z", None), getattr(solution, "z_box", None)
        cert = self._certificate(call, x, z, z_box, recover=False)
        trail.certificate = cert
        if cert.passed:
            return LevelAnswer(x, solution, attempt, cert, True)
        polished = self._polished(call, x, z, z_box, cert, solution, attempt)
        if polished is not None:
            return polished
        if cert.primal_residual <= tol:
            cert = self._certificate(call, x, None, None, recover=True)
            trail.certificate = cert
            if cert.passed:
                return LevelAnswer(x, solution, attempt, cert, True)
        trail.reason = self._rejection(cert, solution, f0)
        if trail.usable is None and cert.primal_residual <= tol and cert.objective <= f0 + tol * (1.0 + abs(f0)):
            trail.usable = LevelAnswer(x, solution, attempt, cert, False)
        return None

    def _polished(
        self,
        call: _QpCall,
        x: np.ndarray,
        z: np.ndarray | None,
        z_box: np.ndarray | None,
        cert: Certificate,
        solution: qpsolvers.Solution,
        attempt: int,
    ) -> LevelAnswer | None:
        """A certified KKT polish of a near-optimal answer (nearly feasible, no worse than x0), or None."""
        tol, f0 = self.tolerance, call.f0
        near = cert.primal_residual <= 100.0 * tol and cert.objective <= f0 + tol * (1.0 + abs(f0))
        if not (self.options.kkt_polish and near):
            return None
        # The active set from the answer alone first (rows it meets within 1e-9: interior-point
        # multipliers of nearly active rows mislead), then from its multipliers.
        for z_start, zb_start, active in ((None, None, 1e-9), (z, z_box, tol)):
            polished = polish(call.P, call.q, call.G, call.h, call.lb, call.ub, x, z_start, zb_start, active=active)
            if polished is None:
                continue
            xp = call.refine(polished[0]) if call.refine is not None else polished[0]
            cert_p = self._certificate(call, xp, polished[2], polished[3], recover=False)
            if cert_p.passed:
                return LevelAnswer(xp, solution, attempt, cert_p, True)
        return None

    def _rejection(self, cert: Certificate, solution: qpsolvers.Solution, f0: float) -> str:
        """Why an answer with certificate ``cert`` is not accepted (the message of the failure)."""
        tol = self.tolerance
        if cert.primal_residual > tol:
            reason = f"{self.solver} answer violates its constraints by {cert.primal_residual:.3g} (tolerance {tol:g})"
        elif cert.objective > f0 and "known feasible point" in cert.reason:
            reason = f"{self.solver} answer is worse than a known feasible point ({cert.objective:.6g} > {f0:.6g})"
        else:
            reason = f"{self.solver} answer not certified: {cert.reason}"
        return reason + ("" if solution.found else f" ({self.solver} reported no solution)")

    def _certificate(
        self, call: _QpCall, x: np.ndarray, z: np.ndarray | None, z_box: np.ndarray | None, recover: bool
    ) -> Certificate:
        """:func:`~qp_baseline.certificate.certify` of ``x`` with this solver's tolerances.

        The cascade's level QPs (dense, finite box, a curvature on every variable) go through
        :func:`~qp_baseline.certificate.certify_dense`: the same verdict, a passing one compiled.
        """
        level_value = None if call.level_value is None else call.level_value(x)
        if isinstance(call.curvature, np.ndarray):
            return certify_dense(
                call.P,
                call.q,
                call.G,
                call.h,
                x,
                call.lb,
                call.ub,
                z,
                z_box,
                call.curvature,
                feasible_objective=call.f0,
                level_value=level_value,
                modulus=call.modulus,
                tolerances=self.certificate_tolerances,
                recover=recover,
            )
        return certify(
            call.P,
            call.q,
            call.G,
            call.h,
            x,
            lb=call.lb,
            ub=call.ub,
            z=z,
            z_box=z_box,
            feasible_objective=call.f0,
            level_value=level_value,
            curvature=call.curvature,
            modulus=call.modulus,
            tolerances=self.certificate_tolerances,
            recover=recover,
        )

    def _call_backend(
        self,
        P: np.ndarray,
        q: np.ndarray,
        G: np.ndarray,
        h: np.ndarray,
        lb: np.ndarray,
        ub: np.ndarray,
        initvals: np.ndarray | None,
        kwargs: Mapping[str, Any],
    ) -> qpsolvers.Solution:
        """One backend call, timed into ``_backend_time``, limited to the call's budget (if any)."""
        kwargs = self._budget_kwargs(self.solver, kwargs)
        has_rows = h.size > 0
        if self._sparse:
            P_arg: Any = spa.csc_matrix(P)
            G_arg: Any = spa.csc_matrix(G) if has_rows else None
        else:
            P_arg, G_arg = P, G if has_rows else None
        problem = qpsolvers.Problem(P_arg, q, G_arg, h if has_rows else None, lb=lb, ub=ub)
        t0 = time.perf_counter()
        try:
            return _solve_quietly(problem, self.solver, self._quiet, initvals=initvals, **kwargs)
        finally:
            self._backend_time += time.perf_counter() - t0


def backend_iterations(solution: qpsolvers.Solution) -> int | None:
    """Backend iteration count, where the backend reports one (not DAQP or Clarabel via qpsolvers)."""
    extras = solution.extras or {}
    info = extras.get("info")
    for key in ("iter", "iters", "iteration"):
        value = getattr(info, key, None)
        if isinstance(value, int | np.integer):
            return int(value)
    if "iterations" in extras:
        it = np.asarray(extras["iterations"]).ravel()
        return int(it[0]) if it.size else None
    return None

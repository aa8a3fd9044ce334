r"""The paper's analytic solver: set-based task-priority inverse kinematics (Di Lillo et al., sec. II).

One control step (docs/design.md §3):

1. Every task is evaluated once at ``kin``. Equality tasks give the CLIK reference of eq. (2),
   :math:`x = \dot\sigma_d + K\tilde\sigma`. A set-based task whose σ is past an activation
   threshold is a *candidate*; its reference is :math:`K(\sigma_s - \sigma)` with σ_s the safety
   threshold it crossed (eq. 7). Tasks with a non-finite σ (no obstacle in range) are inactive.
   Both come from the one control reference of every method (:mod:`tpik.reference`); with its
   gain cap (``gain_cap``, default) gains are capped at ``1/dt``: one explicit-Euler step then
   never overshoots a target or a safety threshold.
2. For each subset S of the candidate set C (a *mode*), the tasks of S are inserted at their own
   priority level as equality tasks, stacked with the level's other rows (eq. 5), and the
   hierarchy is solved by the null-space cascade with damped least squares per level:

   * ``"nsb"`` (default, eq. 4): :math:`\dot q = \dot q_1 + N_{1,1}\dot q_2 + \dots
     + N_{1,h-1}\dot q_h` with :math:`\dot q_k = J_k^\# x_k`;
   * ``"ss"`` (Siciliano–Slotine): :math:`\dot q_k = \dot q_{k-1} + (J_k N_{1,k-1})^\#
     (x_k - J_k \dot q_{k-1})`: each level is compensated for the motion of the levels above.

   With ``compensate_set_tasks`` (default), ``nsb`` solves a level in the compensated form
   whenever the mode inserts one of its set-based tasks; levels of equality tasks keep eq. 4.
   Why: in eq. 4 the inserted task's rate is :math:`J_k\dot q = J_k\dot q_{above} +
   J_kN_{1,k-1}J_k^\#x_k`, so a higher level that pushes the task outward (e.g. a joint limit
   whose motion drives the EE into a wall) makes it cross its safety threshold although the
   task is "active": in the hard random campaign the EE went 7.5 mm past a wall this way
   (seed 759: wall reference −0.0038 m/s, NSB rate −0.0306 m/s). Compensated, the inserted
   task's rate is its reference :math:`K(\sigma_s-\sigma)` whenever the levels above leave it
   the freedom, so it converges to its threshold and never crosses it (docs/design.md §3 step 2; the
   pure eq. 4 stays available with ``compensate_set_tasks = false``).

   :math:`N_{1,k}` is the exact (undamped) projector onto the null space of the augmented
   Jacobian (eqs. 5–6), so a lower level never disturbs a higher one.
3. A mode is *admissible* when no left-out candidate moves further out (eqs. 8–9):
   :math:`J_A\dot q_S \le 0` past an upper threshold, :math:`\ge 0` past a lower one (to a
   small tolerance). With ``return_rate_condition`` (default) a candidate already past its
   *safety* threshold (a moving obstacle or a tracking error put it there) may be left out only
   if :math:`\dot q_S` brings it back at least at its reference rate,
   :math:`J_A\dot q_S \le K(\sigma_{s,u} - \sigma) < 0` (resp.
   :math:`\ge K(\sigma_{s,l} - \sigma) > 0`): a person walking into a still arm must not be
   left out. S = C is always admissible.
4. Among admissible modes, ``selection = "largest_norm"`` (the paper and docs/design.md §3 step 4)
   takes the one of largest :math:`\|\dot q_S\|` (the least restricted motion, Moe et al. 2016;
   ties go to the mode with fewer active tasks); the default ``"fewest_active"`` takes the one
   with the fewest active tasks (ties to the largest norm): a task is released as soon as the
   solution without it is admissible (eqs. 8–9), see :attr:`TpikSettings.selection`. The result is then
   scaled by one factor so that every joint is within its velocity limit (direction kept).
   Uniform scaling keeps every sign of step 3 and only slows the convergence of the active tasks
   to their thresholds, so it never makes a set-based task cross.

Step 1 is the shared task evaluation of every method (:class:`tpik.evaluation.TaskEvaluation`:
the built-in task types compiled, any other task through its own ``compute_state``); the rows
of step 1 and steps 2–4 run in one compiled call in the row space of the tasks
(:func:`tpik.step_rows.tpik_step`, :mod:`tpik.cascade`); the NSB term of a level is solved
once per subset of its candidates and shared by every mode, and modes are tried level-major so
that ties resolve the same way everywhere. This module knows no task type. Above
``max_exhaustive_candidates`` candidates, the 2^|C| enumeration is replaced by *greedy release*:
start from S = C and repeatedly drop the one task whose removal gives the best admissible mode,
while that improves the selection rule: O(|C|²) cascades. Every mode it returns passes step 3,
so the safety guarantee is the same; only optimality among modes is given up.

Damping (sec. II-A): λ of each level comes from the smallest singular value of the matrix that
level inverts — :math:`J_k` in ``nsb`` (eq. 4 inverts each level on its own), :math:`J_k
N_{1,k-1}` in ``ss`` — with :math:`\sigma^* = \|x\|/\|\dot q\|_{\max}`, x being the level's
CLIK reference (``damping_sigma_star = "reference"``, default; the paper's
:math:`\|\tilde\sigma\|` for K = I and σ̇_d = 0; with a gain the reference keeps σ* a ratio of
velocities), or the paper's :math:`\sigma^* = \|\tilde\sigma\|/\|\dot q\|_{\max}` as printed
(``"task_error"``, ``tpik-paper``). As printed the units do not match (σ̃ in m or rad,
‖q̇‖_max in rad/s, σ_min in m/rad): we read ‖σ̃‖ as the rate that closes the error in one second,
i.e. σ̃ over 1 s (K = I s⁻¹), which makes σ* a singular value [m/rad] like σ_min. :math:`\|\dot q\|_{\max}` defaults to
:math:`\|\dot q_{\max}\|_2`, the norm of the joint velocity limits (the largest joint-velocity
norm the arm can produce): damping then acts only when a level alone could exceed what the arm
can do, and the final scaling enforces the per-joint limits. The damping bounds every level's
contribution by :math:`\|\dot q\|_{\max}`.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from robots import Kinematics, Robot
from tpik.cascade import SEARCH_NAMES, STATUS_NO_FINITE_MODE, STATUS_NON_FINITE_ROWS, STATUS_OK, warm_up
from tpik.evaluation import TaskEvaluation
from tpik.exceptions import InvalidSettings, InvalidTaskState, TpikError
from tpik.hierarchy import Hierarchy
from tpik.limits import Limit, VelocityLimit, compose_box, scale_into_box
from tpik.reference import ControlReference
from tpik.step_result import SolverBase, SolveStatus, StepResult, failed
from tpik.step_rows import (
    OUT_CANDIDATES,
    OUT_EVALUATED,
    OUT_HOW,
    OUT_LEVELS,
    OUT_ROWS,
    OUT_STATUS,
    STAGE_EVALUATE,
    STAGE_KINEMATICS,
    STAGE_ROWS,
    tpik_step,
)
from tpik.step_rows import warm_up as warm_up_step

VARIANTS: tuple[str, ...] = ("nsb", "ss")
"""Solver variants; the first is the default."""

SELECTIONS: tuple[str, ...] = ("fewest_active", "largest_norm")
"""Rules to choose among admissible modes (see :class:`TpikSettings`); the first is the default."""

SIGMA_STAR_SOURCES: tuple[str, ...] = ("reference", "task_error")
"""What σ* of the damping is computed from (see :class:`TpikSettings`); the first is the default."""


@dataclass(frozen=True)
class TpikSettings:
    r"""Settings of :class:`TpikSolver`.

    The defaults are the project's ``tpik``. Each way in which it departs from the paper is one
    setting, listed in :data:`DEVIATIONS`; :data:`PAPER_SETTINGS` switches them all back
    (``tpik-paper``).

    Attributes:
        variant: ``"nsb"`` (eq. 4, default) or ``"ss"`` (Siciliano–Slotine, compensated).
        selection: Rule among admissible modes. ``"largest_norm"`` (the paper, docs/design.md §3 step 4,
            Moe et al. 2016): largest :math:`\|\dot q_S\|`, ties to fewer active tasks.
            ``"fewest_active"`` (default; a literal reading of eqs. 8–9: release a task as soon
            as the solution without it is admissible): fewest active tasks, ties to the largest
            norm. Why: a task inserted in its activation band is driven *toward* its safety
            threshold (eq. 7), and a compensated level (``ss``, or ``nsb`` compensating an
            inserted set task) inverts :math:`J_kN_{1,k-1}`, which grows as more tasks are
            inserted. Both add norm to the modes that hold a task, so the largest norm holds a
            task that could be released: it is pulled to its threshold and sticks there
            (``tests/tpik/test_solver_closed_loop.py``), or the choice flips every step between
            holding and releasing (seed 838 of the hard campaign alternated ±0.09 rad/s
            every 10 ms for 0.2 s; with the servo lag of the dynamic arm the EE went 3.5 mm past
            a wall).
        max_exhaustive_candidates: Largest |C| for which all 2^|C| modes are tried; above it
            the greedy release search is used.
        compensate_set_tasks: ``nsb`` only: solve a level in the compensated form whenever the
            mode inserts one of its set-based tasks, so an inserted task tracks its reference
            despite the motion of the levels above (module docstring). False = eq. 4 on every
            level, as the paper writes it. ``ss`` compensates every level anyway.
        return_rate_condition: A candidate already past its safety threshold may be left out
            only if the mode brings it back at least at its reference rate (default); False =
            eqs. 8–9 alone (it may be left out as soon as it does not move further out).
        gain_cap: Cap every gain at 1/dt in the control reference (:mod:`tpik.reference`,
            default, as for HQP and mink); False = the gains as configured (the paper).
        damping_sigma_star: ``"reference"`` (default): :math:`\sigma^* =
            \|\dot\sigma_d + K\tilde\sigma\|/\|\dot q\|_{\max}` from the level's (compensated)
            reference; ``"task_error"``: :math:`\|\tilde\sigma\|/\|\dot q\|_{\max}` as printed
            in sec. II-A (module docstring: how its units are read).
        velocity_norm_max: :math:`\|\dot q\|_{\max}` [rad/s] of the dynamic damping; None =
            the 2-norm of the robot's joint velocity limits.
        rank_tolerance: Singular values at or below this count as zero (projectors and
            inverses) [task unit/rad].
        admissibility_tolerance: Slack on :math:`J_A\dot q` in eqs. 8–9, against round-off
            [task unit/s].
    """

    variant: str = VARIANTS[0]
    selection: str = SELECTIONS[0]
    max_exhaustive_candidates: int = 6
    compensate_set_tasks: bool = True
    return_rate_condition: bool = True
    gain_cap: bool = True
    damping_sigma_star: str = SIGMA_STAR_SOURCES[0]
    velocity_norm_max: float | None = None
    rank_tolerance: float = 1e-6
    admissibility_tolerance: float = 1e-9

    def __post_init__(self) -> None:
        if self.variant not in VARIANTS:
            raise InvalidSettings(f"variant: unknown TPIK variant {self.variant!r}; known: {', '.join(VARIANTS)}")
        if self.selection not in SELECTIONS:
            raise InvalidSettings(f"selection: unknown rule {self.selection!r}; known: {', '.join(SELECTIONS)}")
        if self.damping_sigma_star not in SIGMA_STAR_SOURCES:
            raise InvalidSettings(
                f"damping_sigma_star: unknown source {self.damping_sigma_star!r}; "
                f"known: {', '.join(SIGMA_STAR_SOURCES)}"
            )
        for key in ("compensate_set_tasks", "return_rate_condition", "gain_cap"):
            if not isinstance(getattr(self, key), bool):
                raise InvalidSettings(f"{key}: must be true or false, got {getattr(self, key)!r}")
        if isinstance(self.max_exhaustive_candidates, bool) or not isinstance(self.max_exhaustive_candidates, int):
            raise InvalidSettings(
                f"max_exhaustive_candidates: must be an integer, got {self.max_exhaustive_candidates!r}"
            )
        if not 0 <= self.max_exhaustive_candidates <= 16:
            raise InvalidSettings(
                f"max_exhaustive_candidates: must be in 0..16 (2^16 modes), got {self.max_exhaustive_candidates}"
            )
        if self.velocity_norm_max is not None:
            _check_number("velocity_norm_max", self.velocity_norm_max)
        _check_number("rank_tolerance", self.rank_tolerance)
        _check_number("admissibility_tolerance", self.admissibility_tolerance, allow_zero=True)

    @property
    def deviations(self) -> tuple[str, ...]:
        """Names of the :data:`DEVIATIONS` from the paper these settings keep on."""
        return tuple(name for name, dev in DEVIATIONS.items() if getattr(self, dev.setting) != dev.paper)

    @classmethod
    def from_dict(cls, values: Mapping[str, Any] | None) -> TpikSettings:
        """Build settings from plain data (a config table).

        Raises:
            InvalidSettings: naming the unknown key or the bad value.
        """
        data = dict(values or {})
        known = [f.name for f in dataclasses.fields(cls)]
        for key in data:
            if key not in known:
                raise InvalidSettings(f"unknown TPIK setting '{key}'; known: {', '.join(known)}")
        for key in ("variant", "selection", "damping_sigma_star"):
            if key in data and not isinstance(data[key], str):
                raise InvalidSettings(f"{key}: must be a string, got {data[key]!r}")
        for key in ("velocity_norm_max", "rank_tolerance", "admissibility_tolerance"):
            if data.get(key) is not None:
                _check_number(key, data[key], allow_zero=True)
                data[key] = float(data[key])
        return cls(**data)


@dataclass(frozen=True)
class Deviation:
    """One way the default ``tpik`` departs from the paper: a setting and the paper's value of it.

    Attributes:
        setting: Field of :class:`TpikSettings`.
        paper: The paper's value (``tpik-paper``); ``tpik`` uses the field's default.
        why: One line: what it does and what it was introduced for.
    """

    setting: str
    paper: Any
    why: str


DEVIATIONS: dict[str, Deviation] = {
    "compensated-levels": Deviation(
        "compensate_set_tasks",
        False,
        "a level holding an inserted set task is solved in the compensated form, so a higher level cannot drag it"
        " across its threshold (eq. 4 did: seed 759, 7.5 mm past a wall)",
    ),
    "fewest-active": Deviation(
        "selection",
        "largest_norm",
        "among admissible modes the one with the fewest active tasks instead of the largest norm (which pulled"
        " tasks to their thresholds and chattered: seed 838)",
    ),
    "return-rate": Deviation(
        "return_rate_condition",
        False,
        "a candidate past its safety threshold may be left out only if the mode brings it back at its reference"
        " rate (eqs. 8-9 alone let a still arm ignore a person walking in)",
    ),
    "gain-cap": Deviation(
        "gain_cap",
        False,
        "gains capped at 1/dt in the reference, so one Euler step never overshoots (same reference for HQP and mink)",
    ),
    "reference-damping": Deviation(
        "damping_sigma_star",
        "task_error",
        "sigma* of the damping from the level's reference velocity instead of the task error ||sigma~||",
    ),
}
"""Every deviation of ``tpik`` from the paper, by name (``tpik-no-<name>`` switches one off)."""

PAPER_SETTINGS: dict[str, Any] = {
    **{dev.setting: dev.paper for dev in DEVIATIONS.values()},
    "variant": "nsb",
    "max_exhaustive_candidates": 12,
}
"""``tpik-paper``: eq. 4 at every level, the largest-norm mode admissible by eqs. 8–9 alone, the
damping of sec. II-A with σ* = ‖σ̃‖/‖q̇‖_max, no gain cap; every mode tried up to 12 candidates
(all 12 set tasks of case 2; docs/design.md §3 allows the greedy search only as a documented shortcut)."""


def _check_number(key: str, value: object, allow_zero: bool = False) -> None:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise InvalidSettings(f"{key}: must be a number, got {value!r}")
    ok = math.isfinite(value) and (value >= 0.0 if allow_zero else value > 0.0)
    if not ok:
        raise InvalidSettings(f"{key}: must be finite and {'>=' if allow_zero else '>'} 0, got {value!r}")


_Buffers = tuple[
    np.ndarray,
    np.ndarray,
    np.ndarray,
    np.ndarray,
    np.ndarray,
    np.ndarray,
    np.ndarray,
    np.ndarray,
    np.ndarray,
    np.ndarray,
    np.ndarray,
    np.ndarray,
    np.ndarray,
]
"""The 13 array arguments of :func:`~tpik.step_rows.tpik_step` between ``q`` and ``stage``."""


@dataclass
class _Plan:
    """What TPIK reads of one hierarchy object, built once: its evaluation and the output buffers.

    Attributes:
        evaluation: The shared task evaluation of the hierarchy's tasks.
        level_names: Name of each hierarchy level.
        iout, fout: Output buffers of :func:`~tpik.step_rows.tpik_step`.
        buffers: Every array argument of :func:`~tpik.step_rows.tpik_step` between ``q`` and
            ``stage``, in order (the chain, placements and support of the frames, then the
            evaluation's buffers): one tuple, not a dozen attribute reads per step.
        own_kinematics: Whether the compiled step computes the frames from ``q`` itself (every
            task of a compiled kind and a chain of revolute joints).
        last_ints: ``iout`` of the last step whose report fields were derived.
        last_report: Those fields: inserted task names, names of the levels with rows, search name.
    """

    evaluation: TaskEvaluation
    level_names: tuple[str, ...]
    iout: np.ndarray
    fout: np.ndarray
    buffers: _Buffers
    own_kinematics: bool
    last_ints: list[int] = dataclasses.field(default_factory=list)
    last_report: tuple[tuple[str, ...], list[str], str] = ((), [], "")


def _frame_buffers(
    robot: Robot, ev: TaskEvaluation
) -> tuple[bool, tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
    """Whether the compiled step can compute ``ev``'s frames from ``q``, and the arrays it reads for that.

    Needs every task of a compiled kind (:attr:`TaskEvaluation.compiled_only`) and the robot as a
    chain of revolute joints (:meth:`Robot.revolute_chain`); otherwise the arrays are empty
    placeholders of the right types and the frames come from the snapshot.
    """
    chain = robot.revolute_chain()
    if chain is None or not ev.compiled_only:
        chain_i, chain_f, parent = np.zeros((1, 3), dtype=np.int64), np.zeros((1, 12)), np.zeros(0, dtype=np.int64)
        return False, (chain_i, chain_f, parent, np.zeros((0, 3)), np.zeros((0, ev.nq), dtype=np.bool_))
    frame_parent, frame_t = robot.frame_placements(ev.frame_names)
    _, support = robot.frame_support(ev.frame_names)
    return True, (chain[0], chain[1], frame_parent, frame_t, support)


class TpikSolver(SolverBase):
    """Set-based task-priority inverse kinematics (the paper's solver); see the module docstring.

    Args:
        robot: The robot (``nq`` and the joint velocity limits ``v_max`` are read from it).
        settings: :class:`TpikSettings`; None = defaults.
        name: Method name shown in reports (``"tpik"``, ``"tpik-ss"``).
        limits: Joint limits (:mod:`tpik.limits`) the velocity is scaled into; the robot's
            velocity limits when None.

    Which tasks are set-based, their gains and thresholds are read once per hierarchy object
    (the first time it is solved); targets and obstacle points are read every step, as the
    tasks evaluate them. Build a new :class:`~tpik.hierarchy.Hierarchy` to change gains or
    thresholds.

    Example::

        solver = TpikSolver(robot)
        qdot, report = solver.solve(hierarchy, robot.kinematics(q), dt=0.01)
    """

    VARIANTS: ClassVar[tuple[str, ...]] = VARIANTS

    def __init__(
        self,
        robot: Robot,
        settings: TpikSettings | None = None,
        name: str = "tpik",
        limits: Sequence[Limit] | None = None,
    ) -> None:
        self.robot = robot
        self.settings = settings if settings is not None else TpikSettings()
        self.name = name
        self.nq = int(robot.nq)
        # The final scaling keeps q̇ in the first VelocityLimit (the robot's by default); any other
        # limit is applied after it by scale_into_box (TPIK's joint position limits are the
        # hierarchy's joint-limit tasks, so PositionLimit is not among the defaults).
        self.limits: tuple[Limit, ...] = (VelocityLimit.from_robot(robot),) if limits is None else tuple(limits)
        velocity = next((lim for lim in self.limits if isinstance(lim, VelocityLimit)), None)
        v_max = (velocity or VelocityLimit.from_robot(robot)).v_max
        if v_max.shape != (self.nq,):
            raise InvalidSettings(f"robot '{robot.name}': joint velocity limits must have shape ({self.nq},)")
        self._box_limits = () if all(lim is velocity for lim in self.limits) else self.limits
        # Only stateful limits have an observe hook of their own (Limit.observe is a no-op).
        self._observers = tuple(lim for lim in self.limits if type(lim).observe is not Limit.observe)
        self._inv_v_max = 1.0 / v_max
        s = self.settings
        self.velocity_norm_max = (
            float(np.linalg.norm(v_max)) if s.velocity_norm_max is None else float(s.velocity_norm_max)
        )
        self._ss = s.variant == "ss"
        self._selection = s.selection
        self._largest_norm = self._selection == "largest_norm"
        self._star_from_error = s.damping_sigma_star == "task_error"
        self.reference = ControlReference(gain_cap=s.gain_cap)
        self._flags = np.array(
            [
                self._ss,
                s.compensate_set_tasks,
                self._largest_norm,
                s.return_rate_condition,
                self._star_from_error,
                s.gain_cap,
            ],
            dtype=np.bool_,
        )
        self._reals = np.concatenate(
            [self._inv_v_max, [self.velocity_norm_max, s.rank_tolerance, s.admissibility_tolerance]]
        )
        self._plan_for: Hierarchy | None = None
        self._plan: _Plan | None = None
        warm_up()  # the compiled mode search is loaded now, not at the first control step
        warm_up_step(self.nq)  # and the compiled step (evaluation, rows, frame kernels)

    def __repr__(self) -> str:
        return f"TpikSolver(name={self.name!r}, settings={self.settings})"

    def _compile(self, hierarchy: Hierarchy) -> _Plan:
        """The shared task evaluation and the level of each task, once per hierarchy object."""
        if self._plan_for is hierarchy and self._plan is not None:
            return self._plan
        if not isinstance(hierarchy, Hierarchy):
            raise TpikError(f"{self.name}: expected a tpik Hierarchy, got {type(hierarchy).__name__}")
        levels = [li for li, level in enumerate(hierarchy.levels) for _ in level.tasks]
        tasks = [task for level in hierarchy.levels for task in level.tasks]
        evaluation = TaskEvaluation(tasks, self.robot, levels, jacobians="candidates", compiled_origins=True)
        n_set, n_levels = len(evaluation.set_tasks), len(hierarchy.levels)
        iout = np.zeros(6 + 2 * n_set + n_levels, dtype=np.int64)
        fout = np.zeros(self.nq + 1 + n_levels)
        names = tuple(level.name for level in hierarchy.levels)
        own, chain = _frame_buffers(self.robot, evaluation)
        ev = evaluation
        buffers = (*chain, ev.frames, ev.set_i, ev.set_in, ev.set_out, ev.eq_i, ev.eq_in, ev.eq_out, ev.eq_level)
        self._plan_for, self._plan = hierarchy, _Plan(evaluation, names, iout, fout, buffers, own)
        return self._plan

    def _check_call(self, kin: Kinematics, dt: float) -> None:
        n = self.nq
        if kin.robot is not self.robot and kin.nq != n:
            raise TpikError(f"{self.name}: kinematics of a {kin.nq}-joint robot given to a solver for {n} joints")
        if type(dt) is float and 0.0 < dt < math.inf:
            return
        if not isinstance(dt, int | float) or not (math.isfinite(dt) and dt > 0.0):
            raise TpikError(f"{self.name}: dt must be a finite number > 0 [s], got {dt!r}")

    @staticmethod
    def _gather(plan: _Plan, kin: Kinematics) -> int:
        """Step 1's Python part for this step; returns the stage the compiled step starts from.

        The frames are computed in the compiled step from ``q`` when the plan allows it and
        ``kin`` is a plain snapshot (:data:`~tpik.step_rows.STAGE_KINEMATICS`; pinocchio's data
        is then never computed); otherwise they are read from ``kin``.
        """
        ev = plan.evaluation
        if plan.own_kinematics and type(kin) is Kinematics:
            kin.check_current()
            ev.gather_inputs()
            return STAGE_KINEMATICS
        if ev.fused:
            ev.gather(kin)
            return STAGE_EVALUATE
        ev.evaluate(kin)
        return STAGE_ROWS

    def solve(self, hierarchy: Hierarchy, kin: Kinematics, dt: float) -> StepResult:
        """One control step (:meth:`_solve_step`), then into the box of :attr:`limits` (:mod:`tpik.limits`)."""
        result = self._solve_step(hierarchy, kin, dt)
        if self._box_limits and result.status != SolveStatus.FAILED:
            result.qdot, scale = scale_into_box(result.qdot, compose_box(self._box_limits, kin.q, dt))
            result.extras["limit_scale"] = scale
            if scale < 1.0:
                result.status = SolveStatus.DEGRADED
                note = f"velocity scaled by {scale:.3g} into the limits"
                result.message = f"{result.message}; {note}" if result.message else f"{self.name}: {note}"
        for limit in self._observers:
            limit.observe(result.qdot)
        return result

    def _solve_step(self, hierarchy: Hierarchy, kin: Kinematics, dt: float) -> StepResult:
        """One control step: joint velocities for ``hierarchy`` at ``kin.q`` over ``dt``.

        Step 1 (every task evaluated once, CLIK references of eq. 2, candidates of eq. 7) is
        the shared :class:`~tpik.evaluation.TaskEvaluation`; the rows and steps 2–4 are one
        compiled call (:func:`tpik.step_rows.tpik_step`).

        Args:
            hierarchy: Priority levels, highest first (the same object every step).
            kin: Kinematics snapshot of the robot at the current ``q``.
            dt: Control period [s].

        Returns:
            :class:`~tpik.step_result.StepResult`: ``qdot`` [rad/s] (finite, within the
            velocity limits; zero and FAILED if the computation gave non-finite numbers), the
            inserted set-based tasks (``active_set``), λ per level (``damping``), build/solve
            times, and ``extras``: ``candidates`` (|C|), ``modes_evaluated``, ``search``
            (``none``/``exhaustive``/``greedy``), ``velocity_scale`` (≤ 1), ``variant``.
            DEGRADED (with a ``message``) when a level was damped, the velocity was scaled or
            the greedy search was used.

        Raises:
            InvalidTaskState: a task returned a wrong shape or a non-finite Jacobian.
            TpikError: ``kin`` is of a robot with another number of joints, ``dt`` is not a
                finite number > 0, or ``hierarchy`` is not a :class:`~tpik.hierarchy.Hierarchy`.
        """
        t0 = time.perf_counter()
        self._check_call(kin, dt)
        plan = self._plan if self._plan_for is hierarchy and self._plan is not None else self._compile(hierarchy)
        stage = self._gather(plan, kin)
        t1 = time.perf_counter()
        tpik_step(
            kin.q,
            *plan.buffers,
            stage,
            float(dt),
            self._flags,
            self._reals,
            self.settings.max_exhaustive_candidates,
            plan.iout,
            plan.fout,
        )
        t2 = time.perf_counter()
        return self._result(plan, t0, t1, t2)

    @staticmethod
    def _report_fields(plan: _Plan, ints: list[int]) -> tuple[tuple[str, ...], list[str], str]:
        """Inserted set-task names, names of the levels with rows and the search name of ``iout`` = ``ints``."""
        n_cand, n_levels = ints[OUT_CANDIDATES], ints[OUT_LEVELS]
        cands, inserted = ints[6 : 6 + n_cand], ints[6 + n_cand : 6 + 2 * n_cand]
        levels = ints[6 + 2 * n_cand : 6 + 2 * n_cand + n_levels]
        set_tasks, names = plan.evaluation.set_tasks, plan.level_names
        active = tuple(set_tasks[c].name for c, on in zip(cands, inserted, strict=True) if on)
        return active, [names[li] for li in levels], SEARCH_NAMES[ints[OUT_HOW]]

    def _result(self, plan: _Plan, t0: float, t1: float, t2: float) -> StepResult:
        """The :class:`StepResult` of the compiled step's outputs (status, names, reasons).

        The names derived from the integer outputs are reused while those outputs repeat.
        """
        ints = plan.iout.tolist()  # one conversion: the rest is Python ints and floats
        n, n_cand = self.nq, ints[OUT_CANDIDATES]
        if ints[OUT_ROWS] == 0:
            # Only set-based tasks, all inside their activation thresholds: nothing to do.
            extras = self._extras(n_cand, 0, "none")
            extras["velocity_scale"] = 1.0
            return StepResult(np.zeros(n), SolveStatus.OK, (), t2 - t0, 0.0, {}, "", extras)
        if ints[OUT_STATUS] != STATUS_OK:
            extras = self._extras(n_cand, ints[OUT_EVALUATED], SEARCH_NAMES[ints[OUT_HOW]])
            return self._failure(plan, ints[OUT_STATUS], extras)
        if ints != plan.last_ints:
            plan.last_ints, plan.last_report = ints, self._report_fields(plan, ints)
        active, level_names, search = plan.last_report
        extras = self._extras(n_cand, ints[OUT_EVALUATED], search)
        fout = plan.fout
        floats = fout.tolist()
        scale = floats[n]
        extras["velocity_scale"] = scale
        damping = dict(zip(level_names, floats[n + 1 : n + 1 + len(level_names)], strict=True))
        message = self._reasons(scale, damping, search, n_cand)
        status_out = SolveStatus.DEGRADED if message else SolveStatus.OK
        return StepResult(fout[:n].copy(), status_out, active, t1 - t0, t2 - t1, damping, message, extras)

    def _extras(self, n_cand: int, evaluated: int, search: str) -> dict[str, Any]:
        """``extras`` of a step: |C|, variant, selection rule, modes evaluated, search."""
        return {
            "candidates": n_cand,
            "variant": self.settings.variant,
            "selection": self._selection,
            "modes_evaluated": evaluated,
            "search": search,
        }

    @staticmethod
    def _reasons(scale: float, damping: dict[str, float], search: str, n_cand: int) -> str:
        """Why a solved step is DEGRADED (empty when it is OK): scaling, damped levels, greedy search."""
        damped = [name for name, lam in damping.items() if lam > 0.0]
        if scale >= 1.0 and not damped and search != "greedy":
            return ""
        reasons = []
        if scale < 1.0:
            reasons.append(f"velocity scaled by {scale:.3g} to the joint limits")
        if damped:
            reasons.append(f"damped level(s): {', '.join(damped)}")
        if search == "greedy":
            reasons.append(f"greedy active-set search over {n_cand} candidates")
        return "; ".join(reasons)

    def _failure(self, plan: _Plan, status: int, extras: dict[str, Any]) -> StepResult:
        """FAILED result of a non-OK search status (or the error naming a non-finite Jacobian)."""
        n = self.nq
        if status == STATUS_NON_FINITE_ROWS:
            bad = plan.evaluation.first_non_finite()
            if bad is not None:
                raise InvalidTaskState(f"task '{bad}': jacobian has non-finite entries")
            return failed(n, f"{self.name}: the Gram matrix of the task rows overflowed", **extras)
        if status == STATUS_NO_FINITE_MODE:
            return failed(n, f"{self.name}: every mode gave a non-finite velocity", **extras)
        return failed(n, f"{self.name}: the cascade produced a non-finite velocity", **extras)


def solve_tpik(hierarchy: Hierarchy, kin: Kinematics, dt: float, settings: TpikSettings | None = None) -> StepResult:
    """Functional form of :meth:`TpikSolver.solve` for ``kin.robot`` (builds a solver per call)."""
    return TpikSolver(kin.robot, settings).solve(hierarchy, kin, dt)


__all__ = [
    "DEVIATIONS",
    "PAPER_SETTINGS",
    "SELECTIONS",
    "SIGMA_STAR_SOURCES",
    "VARIANTS",
    "Deviation",
    "InvalidSettings",
    "TpikSettings",
    "TpikSolver",
    "solve_tpik",
]

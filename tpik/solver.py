r"""The paper's analytic solver: set-based task-priority inverse kinematics (Di Lillo et al., sec. II).

One control step (DESIGN §3):

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
   the freedom, so it converges to its threshold and never crosses it (DESIGN §3 step 2; the
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
4. Among admissible modes, ``selection = "largest_norm"`` (the paper and DESIGN §3 step 4)
   takes the one of largest :math:`\|\dot q_S\|` (the least restricted motion, Moe et al. 2016;
   ties go to the mode with fewer active tasks); the default ``"fewest_active"`` takes the one
   with the fewest active tasks (ties to the largest norm): a task is released as soon as the
   solution without it is admissible (eqs. 8–9), see :attr:`TpikSettings.selection`. The result is then
   scaled by one factor so that every joint is within its velocity limit (direction kept).
   Uniform scaling keeps every sign of step 3 and only slows the convergence of the active tasks
   to their thresholds, so it never makes a set-based task cross.

Steps 2–4 run in one compiled call in the row space of the tasks (:mod:`tpik.cascade`); the
NSB term of a level is solved once per subset of its candidates and shared by every mode, and
modes are tried level-major so that ties resolve the same way everywhere. This module keeps the
task evaluation (step 1) and knows no task type: it reads σ, J and the thresholds through the
:class:`~tpik.tasks.task.SetTask` interface. Above
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
from tpik.cascade import (
    SEARCH_NAMES,
    STATUS_NO_FINITE_MODE,
    STATUS_NON_FINITE_ROWS,
    STATUS_OK,
    search_modes,
    warm_up,
)
from tpik.exceptions import InvalidSettings, InvalidTaskState, TpikError
from tpik.hierarchy import Hierarchy
from tpik.limits import Limit, VelocityLimit, compose_box, scale_into_box
from tpik.reference import ControlReference
from tpik.step_result import SolveStatus, StepResult, failed
from tpik.tasks.task import SetTask, Task

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
        selection: Rule among admissible modes. ``"largest_norm"`` (the paper, DESIGN §3 step 4,
            Moe et al. 2016): largest :math:`\|\dot q_S\|`, ties to fewer active tasks.
            ``"fewest_active"`` (default; a literal reading of eqs. 8–9: release a task as soon
            as the solution without it is admissible): fewest active tasks, ties to the largest
            norm. Why: a task inserted in its activation band is driven *toward* its safety
            threshold (eq. 7), and a compensated level (``ss``, or ``nsb`` compensating an
            inserted set task) inverts :math:`J_kN_{1,k-1}`, which grows as more tasks are
            inserted. Both add norm to the modes that hold a task, so the largest norm holds a
            task that could be released: it is pulled to its threshold and sticks there
            (``tests/tpik/test_solver_closed_loop.py``), or the choice flips every step between
            holding and releasing (issue 9: seed 838 of the hard campaign alternated ±0.09 rad/s
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
    def selection_rule(self) -> str:
        """The rule used among admissible modes (``selection``)."""
        return self.selection

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
(all 12 set tasks of case 2; DESIGN §3 allows the greedy search only as a documented shortcut)."""


def _check_number(key: str, value: object, allow_zero: bool = False) -> None:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise InvalidSettings(f"{key}: must be a number, got {value!r}")
    ok = math.isfinite(value) and (value >= 0.0 if allow_zero else value > 0.0)
    if not ok:
        raise InvalidSettings(f"{key}: must be finite and {'>=' if allow_zero else '>'} 0, got {value!r}")


_SetEntry = tuple[Any, SetTask, str, float, float, float, float, float]
"""A set-based task of the plan, thresholds read once: (σ method or None, task, name, gain,
σ_{a,l}, σ_{a,u}, σ_{s,l}, σ_{s,u}). The method is None when ``compute_state`` is overridden."""


@dataclass
class _LevelPlan:
    name: str
    equality: list[Task]
    set_tasks: list[_SetEntry]


class TpikSolver:
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
        self._plan_for: Hierarchy | None = None
        self._plan: list[_LevelPlan] = []
        warm_up()  # the compiled mode search is loaded now, not at the first control step

    def __repr__(self) -> str:
        return f"TpikSolver(name={self.name!r}, settings={self.settings})"

    def _compile(self, hierarchy: Hierarchy) -> list[_LevelPlan]:
        """Sort each level's tasks into equality and set-based ones, once per hierarchy object."""
        if self._plan_for is hierarchy:
            return self._plan
        if not isinstance(hierarchy, Hierarchy):
            raise TpikError(f"{self.name}: expected a tpik Hierarchy, got {type(hierarchy).__name__}")
        plan: list[_LevelPlan] = []
        for level in hierarchy.levels:
            eq: list[Task] = []
            st: list[_SetEntry] = []
            for task in level.tasks:
                if isinstance(task, SetTask):
                    th = task.thresholds
                    # σ and J are read directly unless the task customises its TaskState.
                    # σ alone first; the Jacobian only for candidates (most set tasks are inactive).
                    direct = task.compute_value if type(task).compute_state is SetTask.compute_state else None
                    st.append(
                        (
                            direct,
                            task,
                            task.name,
                            task.gain,
                            th.activation_lower,
                            th.activation_upper,
                            th.safety_lower,
                            th.safety_upper,
                        )
                    )
                else:
                    eq.append(task)
            plan.append(_LevelPlan(level.name, eq, st))
        self._plan_for, self._plan = hierarchy, plan
        return plan

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
        for limit in self.limits:
            limit.observe(result.qdot)
        return result

    def _solve_step(self, hierarchy: Hierarchy, kin: Kinematics, dt: float) -> StepResult:
        """One control step: joint velocities for ``hierarchy`` at ``kin.q`` over ``dt``.

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
        n = self.nq
        if kin.nq != n:
            raise TpikError(f"{self.name}: kinematics of a {kin.nq}-joint robot given to a solver for {n} joints")
        if not (type(dt) is float or isinstance(dt, int | float)) or not (math.isfinite(dt) and dt > 0.0):
            raise TpikError(f"{self.name}: dt must be a finite number > 0 [s], got {dt!r}")
        plan = self._compile(hierarchy)
        reference = self.reference
        from_error = self._star_from_error

        # ---- 1. evaluate every task once; CLIK references (eq. 2) and candidates (eq. 7).
        blocks: list[np.ndarray] = []  # the rows of A, level by level
        x: list[float] = []
        err: list[float] = []  # per row: the task error σ̃ (σ* of the paper's damping)
        row_level: list[int] = []  # per row: index among the levels that have rows
        row_side: list[float] = []  # per row: 0 equality, ±1 candidate past its upper/lower threshold
        level_names: list[str] = []
        cand_names: list[str] = []
        block_names: list[str] = []
        row_shape = (1, n)
        inf = math.inf
        for lp in plan:
            li = len(level_names)
            rows_before = len(x)
            for task in lp.equality:
                state = task.compute_state(kin)
                m = state.value.shape[0]
                if (
                    state.jacobian.shape != (m, n)
                    or state.error.shape != (m,)
                    or state.feedforward.shape != (m,)
                    or state.desired.shape != (m,)
                ):
                    state.validate(task.name, n)  # raises InvalidTaskState naming the array
                x.extend(reference.equality(task, state, dt).tolist())
                if from_error:
                    err.extend(state.error.tolist())
                row_level.extend([li] * m)
                row_side.extend([0.0] * m)
                blocks.append(state.jacobian)
                block_names.append(task.name)
            for direct, set_task, name, _gain, act_lower, act_upper, safe_lower, safe_upper in lp.set_tasks:
                if direct is not None:
                    sigma = float(direct(kin))
                    jac = None
                else:
                    state = set_task.compute_state(kin)
                    state.validate(name, n)
                    sigma, jac = float(state.value[0]), state.jacobian  # shape checked by validate()
                if act_upper <= sigma < inf:
                    side, target = 1.0, safe_upper
                elif -inf < sigma <= act_lower:
                    side, target = -1.0, safe_lower
                else:
                    continue  # inside the activation thresholds, or non-finite σ: inactive
                if jac is None:
                    jac = set_task.compute_jacobian(kin)
                    if jac.shape != row_shape:
                        raise InvalidTaskState(f"task '{name}': jacobian has shape {jac.shape}, expected (1, {n})")
                lo_rate, hi_rate = reference.set_rates(set_task, sigma, dt)
                cand_names.append(name)
                x.append(hi_rate if side > 0.0 else lo_rate)
                if from_error:
                    err.append(target - sigma)
                row_level.append(li)
                row_side.append(side)
                blocks.append(jac)
                block_names.append(name)
            if len(x) > rows_before:
                level_names.append(lp.name)
        n_cand = len(cand_names)
        s = self.settings
        extras: dict[str, Any] = {"candidates": n_cand, "variant": s.variant, "selection": self._selection}
        if not blocks:
            # Only set-based tasks, all inside their activation thresholds: nothing to do.
            extras.update(modes_evaluated=0, search="none", velocity_scale=1.0)
            return StepResult(np.zeros(n), SolveStatus.OK, (), time.perf_counter() - t0, 0.0, {}, "", extras)
        A = np.concatenate(blocks, dtype=float) if len(blocks) > 1 else np.ascontiguousarray(blocks[0], dtype=float)
        t1 = time.perf_counter()

        # ---- 2–4. mode search (cascade per mode, admissibility, selection), q̇ and its scaling.
        x_arr = np.array(x)
        qdot, inserted, lams, status, evaluated, how, scale = search_modes(
            A,
            x_arr,
            np.array(err) if from_error else x_arr,
            np.array(row_level, dtype=np.int64),
            np.array(row_side),
            self._inv_v_max,
            self._ss,
            s.compensate_set_tasks,
            self._largest_norm,
            s.return_rate_condition,
            from_error,
            self.velocity_norm_max,
            s.rank_tolerance,
            s.admissibility_tolerance,
            s.max_exhaustive_candidates,
        )
        t2 = time.perf_counter()
        search = SEARCH_NAMES[how]
        extras["modes_evaluated"] = evaluated
        extras["search"] = search
        if status != STATUS_OK:
            if status == STATUS_NON_FINITE_ROWS:
                _raise_non_finite(block_names, blocks)
                return failed(n, f"{self.name}: the Gram matrix of the task rows overflowed", **extras)
            if status == STATUS_NO_FINITE_MODE:
                return failed(n, f"{self.name}: every mode gave a non-finite velocity", **extras)
            return failed(n, f"{self.name}: the cascade produced a non-finite velocity", **extras)
        extras["velocity_scale"] = scale

        damping = dict(zip(level_names, lams.tolist(), strict=True))
        active = tuple(name for name, on in zip(cand_names, inserted.tolist(), strict=True) if on)
        reasons = []
        if scale < 1.0:
            reasons.append(f"velocity scaled by {scale:.3g} to the joint limits")
        damped = [name for name, lam in damping.items() if lam > 0.0]
        if damped:
            reasons.append(f"damped level(s): {', '.join(damped)}")
        if search == "greedy":
            reasons.append(f"greedy active-set search over {n_cand} candidates")
        return StepResult(
            qdot,
            SolveStatus.DEGRADED if reasons else SolveStatus.OK,
            active,
            t1 - t0,
            t2 - t1,
            damping,
            "; ".join(reasons),
            extras,
        )


def _raise_non_finite(names: list[str], blocks: list[np.ndarray]) -> None:
    """Name the task whose Jacobian has non-finite entries (the slow path of the check).

    Returns without raising when every Jacobian is finite (AAᵀ overflowed): the caller then
    reports a failed step.
    """
    for name, block in zip(names, blocks, strict=True):
        if not np.isfinite(block).all():
            raise InvalidTaskState(f"task '{name}': jacobian has non-finite entries")


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

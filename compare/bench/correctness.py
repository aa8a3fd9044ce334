r"""Timing versus correctness of every HQP backend: two verdicts, the project's and qpbenchmark's.

Every HQP method runs one control step on every state of the stored reference
(:mod:`compare.bench.qp_reference`: the case-2 states and the random set), and each step gets two
verdicts, reported side by side:

**Lexicographic correctness** (the project's own test, of the command): the step's command is
compared with the reference cascade, level by level, in the level's residual norm
:math:`\rho_k = \sqrt{f_k}` [task units / s] (:func:`qp_baseline.lexicographic.level_objectives`):

.. math::
    e_k = \frac{\rho_k(\dot q) - \rho_k(\dot q^{ref})}{1 + \rho_k(\dot q^{ref})}.

The comparison is lexicographic with tolerance ``tol``: the first level with :math:`|e_k| >`
``tol`` decides — *worse* (a level lost against the reference: wrong), *better* (a level won,
possible only because the cascade accepts violations and slacks within its tolerances at the
levels above) — and all levels within ``tol`` is a *match*. **Correct** = match or better. A step
is **flagged** when the method told the caller something went wrong with its QPs: FAILED, a
level dropped, or a level kept without a certificate (``extras["levels_dropped"]``,
``extras["levels_uncertified"]``). A wrong step that is not flagged is **silent**: the failure
the certificate exists to prevent (the acceptance is zero silent steps).

**qpbenchmark's criterion** (of the level QPs): qpbenchmark counts a QP as solved when the primal
residual, the dual residual and the duality gap are all below its tolerance. A step meets it
when every level QP its backend solved does, at :data:`QPBENCHMARK_TOLERANCE` (qpbenchmark's
``mid_accuracy``), with the residuals of the answer the cascade accepted and the multipliers its
certificate used (the largest over the step's levels). Steps that sent no QP to the backend are
left out of this rate. A step can be lexicographically correct and fail this criterion (a dual
residual of 1e-4 with an optimal answer) and, at a level the certificate flags, the other way.

Per method and state set: both rates (correct / states and qpbenchmark-solved / steps with a
backend QP, each with its Wilson 95 % interval), flagged, silent and false-flag counts, the worst
level error, the residuals (primal residual, dual residual, duality gap: median, p95 and worst),
and the step time (kinematics + solve, as the case-2 bench). Methods are timed interleaved:
``rounds`` passes over all states, each state's methods in a rotating order, so a slow phase of a
shared machine hits every method alike. The verdicts of a step are taken from the first pass
(later passes are timing only; a method's warm start then comes from the state before, as in the
first pass).
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any, Literal

import numpy as np
from scipy.stats import binomtest

import robots
from compare.bench.qp_reference import ReferenceEntry
from compare.bench.qp_states import apply_qp_state
from compare.bench.solver_cases import case2_hierarchy
from compare.bench.solvers import build_methods
from qp_baseline.backends import SUPPORTED_SOLVERS
from qp_baseline.lexicographic import level_objectives, level_rows
from robots import Robot
from tpik.hierarchy import Hierarchy
from tpik.step_result import IkSolver, StepResult

TOLERANCE = 1e-5
"""Level error :math:`|e_k|` within which a level matches the reference (relative to 1 + ρ).

Ten times the cascade's own certificate tolerance (1e-6): a level within tolerance at the levels
above may shift the optimum of the levels below by a little more than 1e-6 (the strict optimum's
conditioning); real errors are far above it (0.11 m/s for an OSQP level drop, 2.1e-5 m/s
for the ProxQP one)."""

QPBENCHMARK_TOLERANCE = 1e-6
"""qpbenchmark's ``mid_accuracy`` tolerance on the primal residual, dual residual and duality gap.

Also the tolerance of the cascade's certificate (:mod:`qp_baseline.certificate`)."""

HQP_BACKENDS = tuple(f"hqp-{name}" for name in SUPPORTED_SOLVERS)
"""Default methods of the correctness bench (every supported QP backend)."""

Verdict = Literal["match", "better", "worse"]


@dataclass(frozen=True)
class LevelComparison:
    """A command's level objectives against the reference's.

    Attributes:
        verdict: ``match``, ``better`` or ``worse`` (module docstring).
        level: First level beyond tolerance (None for a match).
        errors: :math:`e_k` per level.
    """

    verdict: Verdict
    level: int | None
    errors: np.ndarray

    @property
    def correct(self) -> bool:
        """Match or better."""
        return self.verdict != "worse"

    @property
    def worst(self) -> float:
        """Largest :math:`e_k` (how far the worst level lost; ≤ 0 when none lost)."""
        return float(self.errors.max()) if self.errors.size else 0.0


def compare_levels(objectives: np.ndarray, reference: np.ndarray, tol: float = TOLERANCE) -> LevelComparison:
    """Lexicographic comparison of level objectives :math:`f_k` with tolerance (module docstring)."""
    rho = np.sqrt(np.maximum(objectives, 0.0))
    rho_ref = np.sqrt(np.maximum(reference, 0.0))
    errors = (rho - rho_ref) / (1.0 + rho_ref)
    for k, e in enumerate(errors):
        if e > tol:
            return LevelComparison("worse", k, errors)
        if e < -tol:
            return LevelComparison("better", k, errors)
    return LevelComparison("match", None, errors)


@dataclass
class StepRecord:
    """One method on one state.

    Attributes:
        method: Method name.
        state: State name.
        state_set: ``case2`` or ``random``.
        status: Step status (``ok``, ``degraded``, ``failed``).
        verdict: Against the reference.
        level: First level beyond tolerance (None for a match).
        worst_error: Largest level error :math:`e_k`.
        flagged: FAILED, a level dropped, or a level uncertified.
        levels_dropped: ``extras["levels_dropped"]``.
        levels_uncertified: ``extras["levels_uncertified"]``.
        qp_calls: Level QPs that went to the backend.
        retries: Retried level QPs.
        primal_residual: Largest primal residual of the step's backend-solved levels (NaN: none).
        dual_residual: Largest dual residual, likewise.
        duality_gap: Largest duality gap, likewise.
        time_us: Median step time over the rounds [µs].
        message: The step's message.
    """

    method: str
    state: str
    state_set: str
    status: str
    verdict: Verdict
    level: int | None
    worst_error: float
    flagged: bool
    levels_dropped: int
    levels_uncertified: int
    qp_calls: int
    retries: int
    primal_residual: float
    dual_residual: float
    duality_gap: float
    time_us: float = math.nan
    message: str = ""

    @property
    def correct(self) -> bool:
        """Match or better."""
        return self.verdict != "worse"

    @property
    def silent(self) -> bool:
        """Wrong and not flagged."""
        return not self.correct and not self.flagged

    def qpbenchmark_solved(self, tol: float = QPBENCHMARK_TOLERANCE) -> bool:
        """Whether the step meets qpbenchmark's criterion: residuals and duality gap all below ``tol``.

        False for a step whose residuals are NaN (no backend QP, or none certified).
        """
        return all(v < tol for v in (self.primal_residual, self.dual_residual, self.duality_gap))


def state_set(name: str) -> str:
    """``case2`` for the case-2 states, ``random`` for the random set."""
    return "case2" if name.startswith("case2") else "random"


def judge_step(
    method: str, entry: ReferenceEntry, result: StepResult, hierarchy: Hierarchy, robot: Robot, tol: float = TOLERANCE
) -> StepRecord:
    """Compare one step's command with the reference and collect its report."""
    state = entry.state
    rows = level_rows(hierarchy, robot.kinematics(state.bench.q), state.dt)
    cmp = compare_levels(level_objectives(rows, np.asarray(result.qdot, dtype=float)), entry.objectives, tol)
    extras = result.extras
    dropped = int(extras.get("levels_dropped", 0) or 0)
    uncertified = int(extras.get("levels_uncertified", 0) or 0)
    certs = list((extras.get("certificates") or {}).values())

    def worst(attr: str) -> float:
        return max((float(getattr(c, attr)) for c in certs), default=math.nan)

    return StepRecord(
        method=method,
        state=state.name,
        state_set=state_set(state.name),
        status=result.status.value,
        verdict=cmp.verdict,
        level=cmp.level,
        worst_error=cmp.worst,
        flagged=result.status.value == "failed" or dropped > 0 or uncertified > 0,
        levels_dropped=dropped,
        levels_uncertified=uncertified,
        qp_calls=int(extras.get("qp_calls", 0) or 0),
        retries=int(extras.get("retries", 0) or 0),
        primal_residual=worst("primal_residual"),
        dual_residual=worst("dual_residual"),
        duality_gap=worst("duality_gap"),
        message=result.message,
    )


def run_correctness_bench(
    method_names: Sequence[str],
    entries: Sequence[ReferenceEntry],
    rounds: int = 3,
    tol: float = TOLERANCE,
    settings: Mapping[str, Mapping[str, Any]] | None = None,
    variants: Mapping[str, IkSolver] | None = None,
) -> list[StepRecord]:
    """Judge and time every method on every reference state (module docstring).

    Args:
        method_names: HQP methods (``hqp-<backend>``); others are skipped with a printed note.
        entries: The reference (:func:`compare.bench.qp_reference.load_reference`).
        rounds: Timed passes over all states (≥ 1); correctness from the first.
        tol: Level tolerance of :func:`compare_levels`.
        settings: Per-method settings for :func:`compare.methods.make_method`.
        variants: Extra solvers by label (e.g. one backend with other settings), timed in the same
            interleaved run.

    Returns:
        One record per (method, state), in state order.
    """
    robot = robots.load(robots.DEFAULT_ROBOT)
    names = [n for n in method_names if n.startswith("hqp-")]
    for n in method_names:
        if n not in names:
            print(f"note: skipping method '{n}' in the correctness bench: only hqp-<backend> solves the cascade")
    solvers: dict[str, IkSolver] = {**build_methods(names, robot, settings), **(variants or {})}
    hierarchies = {name: case2_hierarchy(robot) for name in solvers}
    order = list(solvers)
    records: dict[tuple[str, str], StepRecord] = {}
    times: dict[tuple[str, str], list[float]] = {}
    clock = time.perf_counter_ns
    for round_index in range(max(1, rounds)):
        for i, entry in enumerate(entries):
            state = entry.state
            shift = (i + round_index) % max(1, len(order))
            for name in order[shift:] + order[:shift]:
                hierarchy = hierarchies[name]
                apply_qp_state(hierarchy, state)
                t0 = clock()
                result = solvers[name].solve(hierarchy, robot.kinematics(state.bench.q), state.dt)
                elapsed_us = (clock() - t0) * 1e-3
                times.setdefault((name, state.name), []).append(elapsed_us)
                if round_index == 0:
                    records[(name, state.name)] = judge_step(name, entry, result, hierarchy, robot, tol)
    out = []
    for entry in entries:
        for name in order:
            rec = records[(name, entry.state.name)]
            rec.time_us = float(np.median(times[(name, entry.state.name)]))
            out.append(rec)
    return out


def wilson(count: int, total: int) -> tuple[float, float]:
    """Wilson 95 % interval of the rate ``count / total`` (scipy ``binomtest``)."""
    if total == 0:
        return (math.nan, math.nan)
    ci = binomtest(count, total).proportion_ci(confidence_level=0.95, method="wilson")
    return (float(ci.low), float(ci.high))


def _rate(count: int, total: int) -> dict[str, Any]:
    """``{"count", "runs", "rate", "ci95"}`` with the Wilson interval."""
    return {
        "count": count,
        "runs": total,
        "rate": count / total if total else math.nan,
        "ci95": list(wilson(count, total)),
    }


def _quantiles(values: Iterable[float]) -> dict[str, float | None]:
    """Median and p95 of the finite values; ``max`` the worst, inf included; ``non_finite`` the infinite ones.

    (In JSON an infinite ``max`` is ``null``; ``non_finite`` > 0 says that it was infinite.)
    """
    given = np.array([v for v in values if not math.isnan(v)], dtype=float)
    arr = given[np.isfinite(given)]
    non_finite = float(given.size - arr.size)
    if not given.size:
        return {"median": None, "p95": None, "max": None, "non_finite": 0.0}
    worst = float(given.max())
    if not arr.size:
        return {"median": None, "p95": None, "max": worst, "non_finite": non_finite}
    return {
        "median": float(np.median(arr)),
        "p95": float(np.percentile(arr, 95)),
        "max": worst,
        "non_finite": non_finite,
    }


@dataclass
class Summary:
    """One method on one state set (the rows of the table and of ``bench --json``'s ``correctness``).

    Attributes:
        name: Method.
        states: ``case2`` or ``random``.
        count: States.
        correct: Correct states (match or better): the lexicographic verdict.
        success_rate: ``{"count", "runs", "rate", "ci95"}`` of ``correct`` (the rate form of
            ``sweep_summary.json``, docs/design.md §7, with its Wilson interval).
        flagged: Flagged states.
        silent: Wrong and not flagged.
        false_flags: Correct but flagged.
        failed: FAILED steps.
        levels_dropped: Sum over states.
        levels_uncertified: Sum over states.
        worst_level_error: Largest :math:`e_k` over states.
        primal_residual: Median, p95 and worst (``max``) over the steps with a backend QP.
        dual_residual: Likewise.
        duality_gap: Likewise.
        qpbenchmark_success: ``{"count", "runs", "rate", "ci95"}`` of the steps with a backend QP
            whose level QPs all meet qpbenchmark's criterion at ``qpbenchmark_tolerance``.
        qpbenchmark_tolerance: Its tolerance (:data:`QPBENCHMARK_TOLERANCE`).
        time_us: Step time quantiles over states [µs].
        qp_calls_per_step: Mean backend QPs per step.
        retries: Retried level QPs, summed.
    """

    name: str
    states: str
    count: int
    correct: int
    success_rate: dict[str, Any]
    flagged: int
    silent: int
    false_flags: int
    failed: int
    levels_dropped: int
    levels_uncertified: int
    worst_level_error: float
    primal_residual: dict[str, float | None] = field(default_factory=dict)
    dual_residual: dict[str, float | None] = field(default_factory=dict)
    duality_gap: dict[str, float | None] = field(default_factory=dict)
    time_us: dict[str, float | None] = field(default_factory=dict)
    qp_calls_per_step: float = 0.0
    retries: int = 0
    qpbenchmark_success: dict[str, Any] = field(default_factory=dict)
    qpbenchmark_tolerance: float = QPBENCHMARK_TOLERANCE

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready."""
        return asdict(self)


def summarize(records: Sequence[StepRecord]) -> list[Summary]:
    """One :class:`Summary` per (method, state set), methods in first-seen order, case2 first."""
    methods = list(dict.fromkeys(r.method for r in records))
    keys = sorted(
        dict.fromkeys((r.method, r.state_set) for r in records), key=lambda k: (k[1] != "case2", methods.index(k[0]))
    )
    out = []
    for method, sset in keys:
        rs = [r for r in records if r.method == method and r.state_set == sset]
        n, k = len(rs), sum(r.correct for r in rs)
        with_qp = [r for r in rs if r.qp_calls > 0]
        out.append(
            Summary(
                name=method,
                states=sset,
                count=n,
                correct=k,
                success_rate=_rate(k, n),
                flagged=sum(r.flagged for r in rs),
                silent=sum(r.silent for r in rs),
                false_flags=sum(r.correct and r.flagged for r in rs),
                failed=sum(r.status == "failed" for r in rs),
                levels_dropped=sum(r.levels_dropped for r in rs),
                levels_uncertified=sum(r.levels_uncertified for r in rs),
                worst_level_error=max(r.worst_error for r in rs),
                primal_residual=_quantiles(r.primal_residual for r in with_qp),
                dual_residual=_quantiles(r.dual_residual for r in with_qp),
                duality_gap=_quantiles(r.duality_gap for r in with_qp),
                time_us=_quantiles(r.time_us for r in rs),
                qp_calls_per_step=float(np.mean([r.qp_calls for r in rs])) if rs else 0.0,
                retries=sum(r.retries for r in rs),
                qpbenchmark_success=_rate(sum(r.qpbenchmark_solved() for r in with_qp), len(with_qp)),
            )
        )
    return out

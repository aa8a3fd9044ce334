"""The :class:`~tpik.step_result.StepResult` of one cascade step: q̇, status, active set, extras.

``extras``: ``slacks`` {level: {task: slack}}, ``residuals`` {level: ‖J q̇ − r‖}, ``qp_calls``,
``iterations`` {level: backend iterations, where reported}, ``retries``, ``levels_dropped``,
``levels_uncertified``, ``certificates`` {level or ``"min_norm"``: certificate of each
backend-solved level}, ``min_norm_failure``. A set task is *binding* (in the active set) when one
of its rows is within ``slack_tolerance`` of its relaxed bound at the final q̇ or was relaxed by
more than that; *relaxed* (the step DEGRADED) when its largest slack exceeds ``slack_tolerance``.
"""

from __future__ import annotations

from collections.abc import Mapping

from qp_baseline.cascade_kernels import clip_into
from qp_baseline.certificate import Certificate
from qp_baseline.hqp_cascade import Cascade, CascadeState, LevelFailure
from tpik.step_result import SolveStatus, StepResult, failed


def set_task_report(
    state: CascadeState, cascade: Cascade, slack_tolerance: float
) -> tuple[dict[str, dict[str, float]], list[str], list[str]]:
    """Per level the largest slack of each set task; the binding tasks; the relaxed ones."""
    layout = cascade.layout
    slacks: dict[str, dict[str, float]] = {}
    active: list[str] = []
    relaxed: list[str] = []
    if not state.h_rel.size:
        return slacks, active, relaxed
    # Slacks only come from backend answers: without a backend call they are all zero.
    Gq, h = (layout.G @ state.qd).tolist(), state.h_rel.tolist()
    slack = state.slack.tolist() if state.slack is not None else [0.0] * len(h)
    names, level_of = layout.set_names, layout.set_level
    by_level: dict[int, dict[str, float]] = {}
    for row, task in enumerate(layout.owner.tolist()):
        name, w = names[task], slack[row]
        per_task = by_level.setdefault(level_of[task], {})
        per_task[name] = max(per_task.get(name, 0.0), w)
        if (Gq[row] >= h[row] - slack_tolerance or w > slack_tolerance) and name not in active:
            active.append(name)
        if w > slack_tolerance and name not in relaxed:
            relaxed.append(name)
    for k, per_task in by_level.items():
        slacks[layout.levels[k].name] = per_task
    return slacks, active, relaxed


def _named(cascade: Cascade, certificates: Mapping[int, Certificate]) -> dict[str, Certificate]:
    return {cascade.level_name(k): c for k, c in certificates.items()}


def step_result(
    state: CascadeState, cascade: Cascade, slack_tolerance: float, total_s: float, solve_s: float
) -> StepResult:
    """The step's result from the finished cascade (q̇ clipped into the box, in place).

    Args:
        state: The finished cascade.
        cascade: The cascade that ran (names, set rows, certificates).
        slack_tolerance: A slack above this makes the step DEGRADED [task unit / s].
        total_s: Time of the whole step so far [s].
        solve_s: Time spent in the backend calls and the unconstrained linear solves [s].
    """
    qd = state.qd
    clip_into(qd, state.lb, state.ub)
    slacks, active, relaxed = set_task_report(state, cascade, slack_tolerance)
    if relaxed:
        state.add_message(cascade.method, f"set tasks relaxed (slack > {slack_tolerance:g}): {', '.join(relaxed)}")
        state.status = SolveStatus.DEGRADED
    return StepResult(
        qd,
        state.status,
        tuple(active),
        build_time_s=total_s - solve_s,
        solve_time_s=solve_s,
        message=state.message,
        extras={
            "slacks": slacks,
            "residuals": state.residuals,
            "qp_calls": state.qp_calls,
            "iterations": state.iterations,
            "retries": state.retries,
            "min_norm_failure": state.min_norm_failure,
            "levels_dropped": state.levels_dropped,
            "levels_uncertified": state.levels_uncertified,
            "certificates": _named(cascade, cascade.levels.certificates),
        },
    )


def failed_result(failure: LevelFailure, cascade: Cascade, n: int, total_s: float, solve_s: float) -> StepResult:
    """A FAILED step (zero velocity): every task level dropped; the certificates so far."""
    res = failed(
        n,
        failure.message,
        level=failure.level,
        levels_dropped=cascade.n_levels,
        certificates=_named(cascade, cascade.levels.certificates),
    )
    res.solve_time_s = solve_s
    res.build_time_s = total_s - solve_s
    return res

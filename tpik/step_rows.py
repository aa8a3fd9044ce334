r"""TPIK's rows of one step from the shared task evaluation, and the mode search, in one compiled call.

From the buffers of :class:`tpik.evaluation.TaskEvaluation` this stacks, level by level, the
rows TPIK can use (docs/design.md §3 step 1): every equality row with its CLIK reference
:math:`x = \dot\sigma_d + K\tilde\sigma` (eq. 2), then every *candidate* set task (σ past an
activation threshold) with the rate of the safety threshold it crossed,
:math:`x = K(\sigma_s - \sigma) + f` (eq. 7, f the task's rate feed-forward), K = min(gain, 1/dt) with the gain cap
(:func:`tpik.reference.effective_gain`); then it runs :func:`tpik.cascade.search_modes` on them.
Levels without a row are dropped, as the cascade numbers only the levels that have rows.
"""

from __future__ import annotations

import numba
import numpy as np

from robots.kinematics import chain_frames
from tpik.cascade import search_modes
from tpik.evaluation import (
    EQ_ERROR,
    EQ_FEEDFORWARD,
    EQ_GAIN,
    EQ_JAC,
    SET_FEEDFORWARD,
    SET_GAIN,
    SET_JAC,
    SET_LEVEL,
    SET_SAFE_HI,
    SET_SAFE_LO,
    SET_SIDE,
    SET_SIGMA,
    evaluate_compiled,
)
from tpik.evaluation import warm_up as warm_up_evaluation

STAGE_ROWS, STAGE_EVALUATE, STAGE_KINEMATICS = 0, 1, 2
"""Where :func:`tpik_step` starts: from the evaluated buffers, from the frames (the compiled
evaluation pass first), or from ``q`` (the frames by :func:`robots.kinematics.chain_frames`
first)."""

OUT_STATUS, OUT_EVALUATED, OUT_HOW, OUT_ROWS, OUT_CANDIDATES, OUT_LEVELS = 0, 1, 2, 3, 4, 5
"""Entries of the integer output of :func:`tpik_step`, followed by the candidates' set-task
indices (C), whether each is inserted (C) and the hierarchy level of each level with rows (L)."""


@numba.njit(cache=True, nogil=True)
def _gain(gain: float, dt: float, gain_cap: bool) -> float:
    """K of the reference: ``gain``, capped at 1/dt (as :func:`tpik.reference.effective_gain`)."""
    if gain_cap:
        k_max = 1.0 / dt
        return gain if gain < k_max else k_max
    return gain


@numba.njit(cache=True, nogil=True)
def _count_rows(
    set_out: np.ndarray, set_i: np.ndarray, eq_level: np.ndarray, n_levels: int
) -> tuple[int, int, np.ndarray]:
    """Rows, candidates and the hierarchy level of each level that has rows."""
    R = eq_level.shape[0]
    C = 0
    has = np.zeros(n_levels, dtype=np.bool_)
    for i in range(R):
        has[eq_level[i]] = True
    for s in range(set_out.shape[0]):
        if set_out[s, SET_SIDE] != 0.0:
            C += 1
            has[set_i[s, SET_LEVEL]] = True
    level_map = np.empty(n_levels, dtype=np.int64)
    k = 0
    for li in range(n_levels):
        if has[li]:
            level_map[k] = li
            k += 1
    return R + C, C, level_map[:k]


@numba.njit(cache=True, nogil=True)
def assemble_rows(
    set_i: np.ndarray,
    set_in: np.ndarray,
    set_out: np.ndarray,
    eq_i: np.ndarray,
    eq_in: np.ndarray,
    eq_out: np.ndarray,
    eq_level: np.ndarray,
    n_levels: int,
    dt: float,
    gain_cap: bool,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The stacked rows (module docstring) from the buffers of :class:`~tpik.evaluation.TaskEvaluation`.

    Returns:
        ``(A, x, e, row_level, row_side, cand_task, level_map)``: rows (R, n), references, task
        errors σ̃ (σ_s − σ for a candidate), the index of each row's level among the levels with
        rows, 0/±1 per row, the set-task index of each candidate and the hierarchy level of each
        level with rows.
    """
    n = set_out.shape[1] - SET_JAC
    R, C, level_map = _count_rows(set_out, set_i, eq_level, n_levels)
    A = np.empty((R, n))
    x = np.empty(R)
    e = np.empty(R)
    row_level = np.empty(R, dtype=np.int64)
    row_side = np.zeros(R)
    cand_task = np.empty(C, dtype=np.int64)
    # Gain of each equality row: that of its task (eq_i[:, 2] is the task's first row).
    row_gain = np.empty(eq_level.shape[0])
    for t in range(eq_i.shape[0]):
        first = eq_i[t, 2]
        last = eq_i[t + 1, 2] if t + 1 < eq_i.shape[0] else eq_level.shape[0]
        for i in range(first, last):
            row_gain[i] = eq_in[t, EQ_GAIN]
    r = 0
    c = 0
    i_eq = 0
    i_set = 0
    S = set_out.shape[0]
    for k in range(level_map.shape[0]):
        li = level_map[k]
        while i_eq < eq_level.shape[0] and eq_level[i_eq] == li:
            row = eq_out[i_eq]
            A[r] = row[EQ_JAC:]
            x[r] = row[EQ_FEEDFORWARD] + _gain(row_gain[i_eq], dt, gain_cap) * row[EQ_ERROR]
            e[r] = row[EQ_ERROR]
            row_level[r] = k
            r += 1
            i_eq += 1
        while i_set < S and set_i[i_set, SET_LEVEL] <= li:
            side = set_out[i_set, SET_SIDE]
            if set_i[i_set, SET_LEVEL] == li and side != 0.0:
                sigma = set_out[i_set, SET_SIGMA]
                target = set_in[i_set, SET_SAFE_HI] if side > 0.0 else set_in[i_set, SET_SAFE_LO]
                A[r] = set_out[i_set, SET_JAC:]
                x[r] = _gain(set_in[i_set, SET_GAIN], dt, gain_cap) * (target - sigma) + set_in[i_set, SET_FEEDFORWARD]
                e[r] = target - sigma
                row_level[r] = k
                row_side[r] = side
                cand_task[c] = i_set
                r += 1
                c += 1
            i_set += 1
    return A, x, e, row_level, row_side, cand_task, level_map


@numba.njit(cache=True, nogil=True)
def tpik_step(
    q: np.ndarray,
    chain_i: np.ndarray,
    chain_f: np.ndarray,
    frame_parent: np.ndarray,
    frame_t: np.ndarray,
    support: np.ndarray,
    frames: np.ndarray,
    set_i: np.ndarray,
    set_in: np.ndarray,
    set_out: np.ndarray,
    eq_i: np.ndarray,
    eq_in: np.ndarray,
    eq_out: np.ndarray,
    eq_level: np.ndarray,
    stage: int,
    dt: float,
    flags: np.ndarray,
    reals: np.ndarray,
    max_exhaustive: int,
    iout: np.ndarray,
    fout: np.ndarray,
) -> None:
    """The compiled part of a TPIK step: frames and evaluation (from ``stage`` on), rows, mode search.

    ``stage`` (:data:`STAGE_KINEMATICS` ...): with :data:`STAGE_KINEMATICS` the frames come from
    ``q`` and the revolute chain (``chain_i``, ``chain_f``, ``frame_parent``, ``frame_t``,
    ``support``: :meth:`robots.Robot.revolute_chain`, :meth:`~robots.Robot.frame_placements`,
    :meth:`~robots.Robot.frame_support`); otherwise those are not read.
    ``flags``: (ss, compensate, largest_norm, return_rate, star_from_error, gain_cap);
    ``reals``: (1/v_max per joint..., ‖q̇‖_max, rank tolerance, admissibility tolerance).
    The number of hierarchy levels is ``iout``'s: ``iout`` has 6 + 2·S + L entries (S set
    tasks, L levels), ``fout`` n + 1 + L: q̇ (scaled), the scale factor, λ per level with rows.

    Outputs: ``iout`` (:data:`OUT_STATUS` ...; R = 0: nothing was solved), ``fout``.
    """
    if stage == STAGE_KINEMATICS:
        chain_frames(q, chain_i, chain_f, frame_parent, frame_t, support, frames)
    if stage >= STAGE_EVALUATE:
        evaluate_compiled(q, frames, set_i, set_in, set_out, eq_i, eq_in, eq_out)
    S = set_out.shape[0]
    n_levels = iout.shape[0] - 6 - 2 * S
    n = q.shape[0]
    A, x, e, row_level, row_side, cand_task, level_map = assemble_rows(
        set_i, set_in, set_out, eq_i, eq_in, eq_out, eq_level, n_levels, dt, flags[5]
    )
    R = A.shape[0]
    iout[OUT_ROWS], iout[OUT_CANDIDATES], iout[OUT_LEVELS] = R, cand_task.shape[0], level_map.shape[0]
    if R == 0:
        return
    star_from_error = flags[4]
    qdot, active, lams, status, evaluated, how, scale = search_modes(
        A,
        x,
        e if star_from_error else x,
        row_level,
        row_side,
        reals[:n],
        flags[0],
        flags[1],
        flags[2],
        flags[3],
        star_from_error,
        float(reals[n]),
        float(reals[n + 1]),
        float(reals[n + 2]),
        max_exhaustive,
    )
    iout[OUT_STATUS], iout[OUT_EVALUATED], iout[OUT_HOW] = status, evaluated, how
    _write_outputs(qdot, active, lams, scale, cand_task, level_map, iout, fout)


@numba.njit(cache=True, nogil=True)
def _write_outputs(
    qdot: np.ndarray,
    active: np.ndarray,
    lams: np.ndarray,
    scale: float,
    cand_task: np.ndarray,
    level_map: np.ndarray,
    iout: np.ndarray,
    fout: np.ndarray,
) -> None:
    """The search's results into the output buffers of :func:`tpik_step`."""
    n, C, L = qdot.shape[0], cand_task.shape[0], level_map.shape[0]
    for c in range(C):
        iout[6 + c] = cand_task[c]
        iout[6 + C + c] = 1 if active[c] else 0
    for k in range(L):
        iout[6 + 2 * C + k] = level_map[k]
        fout[n + 1 + k] = lams[k]
    for j in range(n):
        fout[j] = qdot[j]
    fout[n] = scale


def warm_up(nq: int) -> None:
    """Load :func:`tpik_step` (and the shared evaluation) into this process: no control step pays for it."""
    warm_up_evaluation(nq)
    if tpik_step.signatures:
        return
    q = np.zeros(nq)
    q.flags.writeable = False  # as a snapshot's
    chain_i = np.zeros((1, 3), dtype=np.int64)
    for stage in (STAGE_ROWS, STAGE_EVALUATE, STAGE_KINEMATICS):
        tpik_step(
            q,
            chain_i,
            np.zeros((1, 12)),
            np.zeros(0, dtype=np.int64),
            np.zeros((0, 3)),
            np.zeros((0, nq), dtype=np.bool_),
            np.zeros((0, 4, nq)),
            np.zeros((0, 4), dtype=np.int64),
            np.zeros((0, 13)),
            np.zeros((0, SET_JAC + nq)),
            np.zeros((0, 3), dtype=np.int64),
            np.zeros((0, 7)),
            np.zeros((0, EQ_JAC + nq)),
            np.zeros(0, dtype=np.int64),
            stage,
            0.01,
            np.zeros(6, dtype=np.bool_),
            np.ones(nq + 3),
            6,
            np.zeros(6, dtype=np.int64),
            np.zeros(nq + 1),
        )


__all__ = [
    "OUT_CANDIDATES",
    "OUT_EVALUATED",
    "OUT_HOW",
    "OUT_LEVELS",
    "OUT_ROWS",
    "OUT_STATUS",
    "STAGE_EVALUATE",
    "STAGE_KINEMATICS",
    "STAGE_ROWS",
    "assemble_rows",
    "tpik_step",
]

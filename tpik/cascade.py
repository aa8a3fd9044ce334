r"""The priority cascade and the search over active-set modes, compiled, in the row space of the tasks.

Let ``A`` stack every row a step can use (the equality rows of all levels and the row of every
candidate set-based task, level by level) and :math:`G = AA^T` (R × R). Each level's update is
a combination of its own rows and of the rows above it, so every velocity of the cascade is
:math:`\dot q = A^Tz` with :math:`z \in \mathbb{R}^R`; projections and inverses only need
entries of ``G``:

* rows above a level: an incremental Cholesky factor ``L`` of :math:`G_{PP}` over an independent
  subset ``P`` of them (a row whose residual :math:`\|N a\|` is at or below the rank tolerance
  is skipped); the exact null-space projector of the augmented Jacobian (eqs. 5–6) applied to
  :math:`A_K^T y` is :math:`A_K^T y - A_P^T G_{PP}^{-1} G_{PK} y`;
* ``nsb`` (eq. 4), level K: :math:`\dot q_K = J_K^\# x_K`, i.e. :math:`y = (G_{KK}+\lambda^2I)^{-1}x_K`,
  then projected as above. This term does not depend on the levels above, so it is solved once
  per (level, subset of the level's candidates) and shared by every mode;
* ``ss``, level K: :math:`B = J_K N_{1,k-1}`, :math:`BB^T = G_{KK} - G_{KP}G_{PP}^{-1}G_{PK}`
  (a Schur complement), :math:`y = (BB^T + \lambda^2 I)^{-1}(x_K - G_{K\cdot}z)`, :math:`B^Ty`
  projected as above;
* a mode's checks: :math:`J_C\dot q = G_{C\cdot}z` (eqs. 8–9) and :math:`\|\dot q\|^2 = z^TGz`.

Only the chosen mode is mapped back to joint space. The whole search — Gram matrix, every
mode's cascade, the admissibility checks, the selection, :math:`\dot q = A^Tz` and the joint
velocity scaling — is one numba-compiled call (:func:`search_modes`): at these sizes (R ≈ 6,
n = 7) the cost of the step is Python call overhead, not arithmetic, so the search costs about
as much as one NumPy call per step whatever the number of modes (``docs/benchmarks.md``).
The task evaluation is the shared compiled pass of :mod:`tpik.evaluation` (the same for TPIK,
HQP and mink); :mod:`tpik.step_rows` stacks its rows and calls :func:`search_modes` in the same
compiled call. Each part is its own compiled function (:func:`_gram`, :func:`_layout`,
:func:`_exhaustive`, :func:`_greedy`, :func:`_scaled_velocity`; per level :func:`_nsb_level`,
:func:`_ss_level`): a call between compiled functions costs nanoseconds, so the split costs
nothing measurable (``docs/benchmarks.md``, "TPIK speed").
"""

from __future__ import annotations

import math

import numba
import numpy as np

from tpik.dls import backward, forward, gram_dls_star

SEARCH_NONE, SEARCH_EXHAUSTIVE, SEARCH_GREEDY = 0, 1, 2
"""Codes of the search used (``how`` of :func:`search_modes`)."""

SEARCH_NAMES: tuple[str, ...] = ("none", "exhaustive", "greedy")
"""Report names of the search codes, by code."""

STATUS_OK, STATUS_NO_FINITE_MODE, STATUS_NON_FINITE_VELOCITY, STATUS_NON_FINITE_ROWS = 0, 1, 2, 3
"""Outcome codes of :func:`search_modes`: solved; every mode non-finite; the chosen mode's
velocity non-finite; a row of ``A`` (or its Gram matrix) non-finite (nothing solved)."""


_MAX_TABLE_CANDIDATES = 8
"""The NSB term is cached per (level, subset) when no level has more candidates than this."""

# Argument bundles of the compiled functions (numba ignores the annotations).
_Layout = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]  # eq_ptr, eq_rows, cand_ptr, cand_row
_Params = tuple[np.ndarray, bool, bool, bool, float, float]  # e, star_from_error, ss, compensate, vnorm, tol
_Cache = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]  # t_has, t_y, t_c, t_lam
_Work = tuple[np.ndarray, np.ndarray, np.ndarray]  # iw, fw, mw
_Problem = tuple[np.ndarray, np.ndarray, _Layout, np.ndarray, _Params, _Cache, _Work]  # G, x, ..., cand_side
_Checks = tuple[float, bool, bool]  # admissibility tolerance, return_rate, largest_norm


@numba.njit(cache=True, nogil=True)
def _level_rows(
    li: int,
    eq_ptr: np.ndarray,
    eq_rows: np.ndarray,
    cand_ptr: np.ndarray,
    cand_row: np.ndarray,
    in_mode: np.ndarray,
    K: np.ndarray,
) -> tuple[int, int]:
    """Rows of level ``li`` in the mode (equality rows, then inserted candidates) into ``K``.

    Returns:
        (number of rows m, bits of the level's inserted candidates).
    """
    m = 0
    for e in range(eq_ptr[li], eq_ptr[li + 1]):
        K[m] = eq_rows[e]
        m += 1
    sub = 0
    for c in range(cand_ptr[li], cand_ptr[li + 1]):
        if in_mode[c]:
            K[m] = cand_row[c]
            m += 1
            sub |= 1 << (c - cand_ptr[li])
    return m, sub


@numba.njit(cache=True, nogil=True)
def _add_rows(
    G: np.ndarray, K: np.ndarray, m: int, P: np.ndarray, n_p: int, Lc: np.ndarray, w: np.ndarray, tol2: float
) -> int:
    """Extend the independent rows ``P[:n_p]`` and the Cholesky factor ``Lc`` of G_PP with K.

    Returns:
        The new number of independent rows.
    """
    for a in range(m):
        k = K[a]
        d = G[k, k]
        for j in range(n_p):  # forward substitution Lc w = G_Pk
            acc = G[k, P[j]]
            for t in range(j):
                acc -= Lc[j, t] * w[t]
            acc /= Lc[j, j]
            w[j] = acc
            d -= acc * acc
        if d > tol2:
            for t in range(n_p):
                Lc[n_p, t] = w[t]
            Lc[n_p, n_p] = math.sqrt(d)
            P[n_p] = k
            n_p += 1
    return n_p


@numba.njit(cache=True, nogil=True)
def _own_solution(
    G: np.ndarray,
    x: np.ndarray,
    e: np.ndarray,
    K: np.ndarray,
    m: int,
    vnorm: float,
    tol: float,
    S: np.ndarray,
    r: np.ndarray,
    work: np.ndarray,
    y: np.ndarray,
    c: np.ndarray,
) -> float:
    r"""NSB term of one level: :math:`y = (G_{KK}+\lambda^2I)^{-1}x_K` and :math:`c = G_{\cdot K}y`.

    λ from :math:`\sigma^* = \|e_K\|/\|\dot q\|_{\max}` (``e`` is ``x`` itself, or the task
    errors σ̃, see :func:`search_modes`).

    Returns:
        λ.
    """
    en2 = 0.0
    for a in range(m):
        r[a] = x[K[a]]
        en2 += e[K[a]] * e[K[a]]
        for b in range(m):
            S[a, b] = G[K[a], K[b]]
    lam = gram_dls_star(S, r, m, math.sqrt(en2) / vnorm, tol, work, y)
    for j in range(G.shape[0]):
        acc = 0.0
        for b in range(m):
            if y[b] != 0.0:
                acc += G[j, K[b]] * y[b]
        c[j] = acc
    return lam


@numba.njit(cache=True, nogil=True)
def _nsb_level(
    G: np.ndarray,
    x: np.ndarray,
    li: int,
    sub: int,
    m: int,
    n_p: int,
    params: tuple[np.ndarray, bool, bool, bool, float, float],
    cache: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray],
    work: tuple[np.ndarray, np.ndarray, np.ndarray],
    z: np.ndarray,
) -> float:
    r"""NSB (eq. 4) of level ``li``: :math:`\dot q_K = J_K^\# x_K = A_K^T y` added to ``z``.

    The term does not depend on the levels above, so it is taken from (or stored in) the cache
    per (level, subset ``sub`` of the level's candidates). Leaves :math:`w = L^{-1}G_{PK}y` in
    the workspace for the projection (:func:`_cascade`).

    Returns:
        λ of the level.
    """
    e, _, _, _, vnorm, tol = params
    t_has, t_y, t_c, t_lam = cache
    iw, fw, mw = work
    K, P = iw[0], iw[1]
    r, y, gP, w, c_own = fw[0], fw[1], fw[2], fw[4], fw[5]
    S, Lc, scratch = mw[0], mw[1], mw[3]
    if sub < t_has.shape[1]:
        if not t_has[li, sub]:
            t_lam[li, sub] = _own_solution(G, x, e, K, m, vnorm, tol, S, r, scratch, t_y[li, sub], t_c[li, sub])
            t_has[li, sub] = True
        yv, cv, lam = t_y[li, sub], t_c[li, sub], t_lam[li, sub]
    else:
        lam = _own_solution(G, x, e, K, m, vnorm, tol, S, r, scratch, y, c_own)
        yv, cv = y, c_own
    for b in range(m):
        z[K[b]] += yv[b]
    if n_p > 0:
        for t in range(n_p):
            gP[t] = cv[P[t]]
        forward(Lc, gP, n_p, w)
    return lam


@numba.njit(cache=True, nogil=True)
def _ss_level(
    G: np.ndarray,
    x: np.ndarray,
    m: int,
    n_p: int,
    params: tuple[np.ndarray, bool, bool, bool, float, float],
    work: tuple[np.ndarray, np.ndarray, np.ndarray],
    z: np.ndarray,
) -> float:
    r"""Compensated (SS) level: :math:`B = J_K N`, :math:`BB^T = G_{KK} - W^TW`, :math:`W = L^{-1}G_{PK}`.

    The reference is compensated for the motion of the levels above,
    :math:`x_K - J_K\dot q_{above}`; :math:`B^Ty` is added to ``z`` and
    :math:`w = W y` left in the workspace for the projection (:func:`_cascade`).

    Returns:
        λ of the level.
    """
    e, star_from_error, _, _, vnorm, tol = params
    iw, fw, mw = work
    R = G.shape[0]
    K, P = iw[0], iw[1]
    r, y, gP, w = fw[0], fw[1], fw[2], fw[4]
    S, Lc, W, scratch = mw[0], mw[1], mw[2], mw[3]
    for a in range(m):
        ka = K[a]
        acc = x[ka]
        for j in range(R):
            if z[j] != 0.0:
                acc -= G[ka, j] * z[j]
        r[a] = acc
    if n_p > 0:
        for a in range(m):
            for t in range(n_p):
                gP[t] = G[P[t], K[a]]
            forward(Lc, gP, n_p, W[a])
        for a in range(m):
            for b in range(m):
                acc = G[K[a], K[b]]
                for t in range(n_p):
                    acc -= W[a, t] * W[b, t]
                S[a, b] = acc
    else:
        for a in range(m):
            for b in range(m):
                S[a, b] = G[K[a], K[b]]
    sn2 = 0.0
    for a in range(m):
        v = e[K[a]] if star_from_error else r[a]
        sn2 += v * v
    lam = gram_dls_star(S, r, m, math.sqrt(sn2) / vnorm, tol, scratch, y)
    if n_p > 0:
        for t in range(n_p):
            acc = 0.0
            for b in range(m):
                acc += W[b, t] * y[b]
            w[t] = acc
    for b in range(m):
        z[K[b]] += y[b]
    return lam


@numba.njit(cache=True, nogil=True)
def _cascade(
    G: np.ndarray,
    x: np.ndarray,
    layout: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray],
    in_mode: np.ndarray,
    params: tuple[np.ndarray, bool, bool, bool, float, float],
    cache: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray],
    work: tuple[np.ndarray, np.ndarray, np.ndarray],
    z: np.ndarray,
    lams: np.ndarray,
) -> None:
    r"""Solve one mode through every level into ``z`` (row coordinates) and ``lams`` (λ per level).

    A level is solved in the compensated (SS) form (:func:`_ss_level`) when ``ss`` is set, or
    when ``compensate`` is set and the mode inserts one of the level's candidates; else by eq. 4
    (NSB, :func:`_nsb_level`). σ* of a level's damping is the norm of its rows of ``e`` (over
    ‖q̇‖_max) in eq. 4, and in the compensated form that of ``e`` when ``star_from_error`` is
    set, else that of the compensated reference :math:`x_K - J_K\dot q_{above}` (``e`` is ``x``
    then). Each level's term is then projected on the null space of the rows above.

    ``params`` is (e, star_from_error, ss, compensate, ‖q̇‖_max, rank tolerance). ``layout`` is
    (eq_ptr, eq_rows, cand_ptr, cand_row): each level's equality rows and candidates.
    ``cache`` is (t_has, t_y, t_c, t_lam): the NSB term per (level, subset of the level's
    candidates), shared across modes; ``t_has`` with zero columns disables it (too many
    subsets to tabulate). ``work`` is (iw (2, R) int, fw (6, R), mw (4, R, R)) workspaces.
    """
    _, _, ss, compensate, _, tol = params
    eq_ptr, eq_rows, cand_ptr, cand_row = layout
    iw, fw, mw = work
    n_levels = eq_ptr.shape[0] - 1
    K, P = iw[0], iw[1]
    w, u = fw[4], fw[3]
    Lc = mw[1]
    for j in range(G.shape[0]):
        z[j] = 0.0
    n_p = 0
    for li in range(n_levels):
        m, sub = _level_rows(li, eq_ptr, eq_rows, cand_ptr, cand_row, in_mode, K)
        if m == 0:
            lams[li] = 0.0
            continue
        if not (ss or (compensate and sub != 0)):
            lam = _nsb_level(G, x, li, sub, m, n_p, params, cache, work, z)
        else:
            lam = _ss_level(G, x, m, n_p, params, work, z)
        if n_p > 0:
            # Remove the part of A_Kᵀ y in the span of the rows above: A_Pᵀ G_PP⁻¹ G_PK y.
            backward(Lc, w, n_p, u)
            for t in range(n_p):
                z[P[t]] -= u[t]
        lams[li] = lam
        if li < n_levels - 1:
            n_p = _add_rows(G, K, m, P, n_p, Lc, w, tol * tol)


@numba.njit(cache=True, nogil=True)
def _better(norm2: float, n_active: int, best_norm2: float, best_n_active: int, largest_norm: bool) -> bool:
    """Whether a mode beats the incumbent under the selection rule (ties within 1e-12 relative)."""
    close = abs(norm2 - best_norm2) <= 1e-12 * (1.0 + max(norm2, best_norm2))
    if largest_norm:
        return n_active < best_n_active if close else norm2 > best_norm2
    if n_active != best_n_active:
        return n_active < best_n_active
    return norm2 > best_norm2 and not close


@numba.njit(cache=True, nogil=True)
def _check(
    G: np.ndarray,
    z: np.ndarray,
    x: np.ndarray,
    in_mode: np.ndarray,
    cand_row: np.ndarray,
    cand_side: np.ndarray,
    adm_tol: float,
    return_rate: bool,
    gz: np.ndarray,
) -> tuple[float, bool]:
    r"""Norm and admissibility of a solved mode.

    A left-out candidate c (side s = +1 upper, −1 lower, reference :math:`x_c = K(\sigma_s -
    \sigma)`) is admissible when :math:`s\,J_c\dot q \le \min(0, s\,x_c) +` ``adm_tol``:

    * inside its safety threshold (:math:`s\,x_c \ge 0`): it does not move further out, the
      paper's eqs. 8–9;
    * past it (a moving obstacle or a tracking error put it there, :math:`s\,x_c < 0`): the
      solution without it brings it back at least as fast as inserting it would. Otherwise a
      task the arm is not moving, e.g. an obstacle distance the person closes, would be left
      out while violated and the arm would never react. Without ``return_rate`` (the paper's
      eqs. 8–9 alone) the bound is 0 on both sides.

    Returns:
        (:math:`\|\dot q\|^2 = z^TGz`, admissible).
    """
    R = G.shape[0]
    norm2 = 0.0
    for i in range(R):
        acc = 0.0
        for j in range(R):
            acc += G[i, j] * z[j]
        gz[i] = acc
        norm2 += z[i] * acc
    for c in range(cand_row.shape[0]):
        r = cand_row[c]
        s = cand_side[c]
        bound = min(0.0, x[r] * s) if return_rate else 0.0
        if not in_mode[c] and gz[r] * s > bound + adm_tol:
            return norm2, False
    return norm2, True


@numba.njit(cache=True, nogil=True)
def search_modes(
    A: np.ndarray,
    x: np.ndarray,
    e: np.ndarray,
    row_level: np.ndarray,
    row_side: np.ndarray,
    inv_v_max: np.ndarray,
    ss: bool,
    compensate: bool,
    largest_norm: bool,
    return_rate: bool,
    star_from_error: bool,
    velocity_norm_max: float,
    rank_tol: float,
    admissibility_tol: float,
    max_exhaustive: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int, int, int, float]:
    r"""One control step's mode search (docs/design.md §3, paper eqs. 4–9), from the stacked rows to q̇.

    Modes are enumerated level-major (the first level's candidate subsets vary slowest, each
    level's subsets in binary order), so ties are broken the same way on every machine.
    Up to ``max_exhaustive`` candidates every mode is tried; above, *greedy release* from
    S = C drops, one at a time, the task whose removal gives the best admissible mode while
    that improves the selection rule.

    Args:
        A: Stacked rows, level by level, each level's equality rows before its candidates.
            Shape (R, n).
        x: CLIK reference of every row [task unit/s]. Shape (R,).
        e: Per row, what σ* of the damping is the norm of (over ``velocity_norm_max``): ``x``
            itself, or the task error σ̃ (the paper's sec. II-A as printed). Shape (R,).
        row_level: Index of each row's level (non-decreasing, levels with a row numbered
            0..L−1). Shape (R,).
        row_side: 0 for an equality row; +1 / −1 for a candidate past its upper / lower
            activation threshold. Shape (R,).
        inv_v_max: 1 / joint velocity limits [s/rad]. Shape (n,).
        ss: Siciliano–Slotine variant instead of NSB (eq. 4).
        compensate: NSB only: solve a level in the compensated form whenever the mode inserts
            one of its set-based tasks (:attr:`tpik.solver.TpikSettings.compensate_set_tasks`).
        largest_norm: Selection rule: largest norm first (else fewest active first).
        return_rate: A left-out candidate past its safety threshold must come back at least at
            its reference rate (:func:`_check`); False = eqs. 8–9 alone.
        star_from_error: Compensated levels take σ* from ``e`` too (else from their
            compensated reference).
        velocity_norm_max: :math:`\|\dot q\|_{\max}` of the damping [rad/s].
        rank_tol: Rank tolerance on singular values.
        admissibility_tol: Slack on :math:`J_c\dot q` in eqs. 8–9 [task unit/s].
        max_exhaustive: Largest |C| enumerated exhaustively.

    Returns:
        ``(qdot, active, lams, status, evaluated, how, scale)``: q̇ [rad/s] scaled into the
        joint velocity limits (direction kept), which candidates are inserted (shape (C,), in
        row order), λ per level, a ``STATUS_*`` code, modes solved, a ``SEARCH_*`` code and the
        velocity scale factor (≤ 1).
    """
    R, n = A.shape
    n_levels = 0 if R == 0 else row_level[R - 1] + 1
    qdot = np.zeros(n)
    lams = np.zeros(n_levels)
    G, finite = _gram(A)  # a non-finite row shows here
    layout, cand_side = _layout(row_level, row_side, n_levels)
    n_cand = cand_side.shape[0]
    active = np.zeros(n_cand, dtype=np.bool_)
    if not finite:
        return qdot, active, lams, STATUS_NON_FINITE_ROWS, 0, SEARCH_NONE, 1.0
    params = (e, star_from_error, ss, compensate, velocity_norm_max, rank_tol)
    cache = _nsb_cache(layout[2], n_levels, R, ss)
    work = (np.empty((2, R), dtype=np.int64), np.empty((6, R)), np.empty((4, R, R)))
    best_z = np.zeros(R)
    problem = (G, x, layout, cand_side, params, cache, work)
    checks = (admissibility_tol, return_rate, largest_norm)
    if n_cand == 0:
        _cascade(G, x, layout, np.zeros(0, dtype=np.bool_), params, cache, work, best_z, lams)
        found, evaluated, how = True, 1, SEARCH_NONE
    elif n_cand <= max_exhaustive:
        found, evaluated = _exhaustive(problem, checks, best_z, lams, active)
        how = SEARCH_EXHAUSTIVE
    else:
        found, evaluated = _greedy(problem, checks, best_z, lams, active)
        how = SEARCH_GREEDY
    if not found:
        return qdot, active, lams, STATUS_NO_FINITE_MODE, evaluated, how, 1.0
    scale = _scaled_velocity(A, best_z, inv_v_max, qdot)
    if not math.isfinite(scale):
        return qdot, active, lams, STATUS_NON_FINITE_VELOCITY, evaluated, how, 1.0
    return qdot, active, lams, STATUS_OK, evaluated, how, scale


@numba.njit(cache=True, nogil=True)
def _gram(A: np.ndarray) -> tuple[np.ndarray, bool]:
    """:math:`G = AA^T` and whether every entry is finite."""
    R, n = A.shape
    G = np.empty((R, R))
    finite = True
    for i in range(R):
        for j in range(i + 1):
            acc = 0.0
            for k in range(n):
                acc += A[i, k] * A[j, k]
            G[i, j] = acc
            G[j, i] = acc
            if not math.isfinite(acc):
                finite = False
    return G, finite


@numba.njit(cache=True, nogil=True)
def _layout(
    row_level: np.ndarray, row_side: np.ndarray, n_levels: int
) -> tuple[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray], np.ndarray]:
    """(eq_ptr, eq_rows, cand_ptr, cand_row) of :func:`_cascade` and each candidate's side."""
    R = row_level.shape[0]
    n_cand = 0
    for i in range(R):
        if row_side[i] != 0.0:
            n_cand += 1
    eq_ptr = np.zeros(n_levels + 1, dtype=np.int64)
    cand_ptr = np.zeros(n_levels + 1, dtype=np.int64)
    eq_rows = np.empty(R - n_cand, dtype=np.int64)
    cand_row = np.empty(n_cand, dtype=np.int64)
    cand_side = np.empty(n_cand)
    ne = 0
    nc = 0
    for i in range(R):
        li = row_level[i]
        if row_side[i] == 0.0:
            eq_rows[ne] = i
            ne += 1
        else:
            cand_row[nc] = i
            cand_side[nc] = row_side[i]
            nc += 1
        eq_ptr[li + 1] = ne
        cand_ptr[li + 1] = nc
    for li in range(n_levels):  # levels without rows of their own keep the previous counts
        if eq_ptr[li + 1] < eq_ptr[li]:
            eq_ptr[li + 1] = eq_ptr[li]
        if cand_ptr[li + 1] < cand_ptr[li]:
            cand_ptr[li + 1] = cand_ptr[li]
    return (eq_ptr, eq_rows, cand_ptr, cand_row), cand_side


@numba.njit(cache=True, nogil=True)
def _nsb_cache(
    cand_ptr: np.ndarray, n_levels: int, R: int, ss: bool
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Empty NSB cache per (level, subset of the level's candidates); no columns if too many subsets."""
    max_level_cands = 0
    for li in range(n_levels):
        max_level_cands = max(max_level_cands, cand_ptr[li + 1] - cand_ptr[li])
    n_sub = 1 << max_level_cands if (not ss and max_level_cands <= _MAX_TABLE_CANDIDATES) else 0
    t_has = np.zeros((n_levels, n_sub), dtype=np.bool_)
    return t_has, np.empty((n_levels, n_sub, R)), np.empty((n_levels, n_sub, R)), np.empty((n_levels, n_sub))


@numba.njit(cache=True, nogil=True)
def _exhaustive(
    problem: _Problem, checks: _Checks, best_z: np.ndarray, lams: np.ndarray, active: np.ndarray
) -> tuple[bool, int]:
    """Every mode, level-major (the first level's subsets vary slowest, each level's in binary order).

    ``problem`` is (G, x, layout, cand_side, params, cache, work), ``checks`` (admissibility
    tolerance, return_rate, largest_norm). The best admissible mode goes into ``best_z``,
    ``lams``, ``active``.

    Returns:
        (whether an admissible finite mode was found, modes solved).
    """
    G, x, layout, cand_side, params, cache, work = problem
    adm_tol, return_rate, largest_norm = checks
    cand_ptr, cand_row = layout[2], layout[3]
    n_cand, R, n_levels = cand_row.shape[0], G.shape[0], lams.shape[0]
    in_mode = np.zeros(n_cand, dtype=np.bool_)
    z, gz, trial_lams = np.empty(R), np.empty(R), np.zeros(n_levels)
    found, evaluated, best_norm2, best_active = False, 0, math.nan, 0
    for code in range(1 << n_cand):
        # Decode level-major: the last level's subset is the lowest digit.
        rest = code
        n_in = 0
        for li in range(n_levels - 1, -1, -1):
            width = cand_ptr[li + 1] - cand_ptr[li]
            bits = rest & ((1 << width) - 1)
            rest >>= width
            for j in range(width):
                on = (bits >> j) & 1 == 1
                in_mode[cand_ptr[li] + j] = on
                if on:
                    n_in += 1
        _cascade(G, x, layout, in_mode, params, cache, work, z, trial_lams)
        evaluated += 1
        norm2, admissible = _check(G, z, x, in_mode, cand_row, cand_side, adm_tol, return_rate, gz)
        if not math.isfinite(norm2) or not admissible:
            continue
        if found and not _better(norm2, n_in, best_norm2, best_active, largest_norm):
            continue
        found = True
        best_norm2, best_active = norm2, n_in
        best_z[:] = z
        lams[:] = trial_lams
        active[:] = in_mode
    return found, evaluated


@numba.njit(cache=True, nogil=True)
def _greedy(
    problem: _Problem, checks: _Checks, best_z: np.ndarray, lams: np.ndarray, active: np.ndarray
) -> tuple[bool, int]:
    """Greedy release from S = C: drop, one at a time, the task whose removal gives the best admissible mode.

    Stops when no removal improves the selection rule; O(|C|²) cascades. Arguments and result
    as :func:`_exhaustive`.
    """
    G, x, layout, cand_side, params, cache, work = problem
    adm_tol, return_rate, largest_norm = checks
    cand_row = layout[3]
    n_cand, R, n_levels = cand_row.shape[0], G.shape[0], lams.shape[0]
    in_mode = np.ones(n_cand, dtype=np.bool_)
    z, gz, trial_lams = np.empty(R), np.empty(R), np.zeros(n_levels)
    _cascade(G, x, layout, in_mode, params, cache, work, z, trial_lams)
    evaluated = 1
    norm2, _ = _check(G, z, x, in_mode, cand_row, cand_side, adm_tol, return_rate, gz)
    found, best_norm2, best_active = False, math.nan, 0
    if math.isfinite(norm2):  # S = C is always admissible
        found, best_norm2, best_active = True, norm2, n_cand
        best_z[:] = z
        lams[:] = trial_lams
        active[:] = True
    step_z, step_lams, step_active = np.empty(R), np.empty(n_levels), np.zeros(n_cand, dtype=np.bool_)
    while found and best_active > 0:
        step_found, step_norm2 = False, math.nan
        for drop in range(n_cand):
            if not active[drop]:
                continue
            in_mode[:] = active
            in_mode[drop] = False
            _cascade(G, x, layout, in_mode, params, cache, work, z, trial_lams)
            evaluated += 1
            norm2, admissible = _check(G, z, x, in_mode, cand_row, cand_side, adm_tol, return_rate, gz)
            if not math.isfinite(norm2) or not admissible:
                continue
            if step_found and not _better(norm2, best_active - 1, step_norm2, best_active - 1, largest_norm):
                continue
            step_found, step_norm2 = True, norm2
            step_z[:] = z
            step_lams[:] = trial_lams
            step_active[:] = in_mode
        if not step_found or not _better(step_norm2, best_active - 1, best_norm2, best_active, largest_norm):
            break
        best_norm2, best_active = step_norm2, best_active - 1
        best_z[:] = step_z
        lams[:] = step_lams
        active[:] = step_active
    return found, evaluated


@numba.njit(cache=True, nogil=True)
def _scaled_velocity(A: np.ndarray, z: np.ndarray, inv_v_max: np.ndarray, qdot: np.ndarray) -> float:
    r""":math:`\dot q = A^Tz` into ``qdot``, scaled by one factor into the joint velocity limits (direction kept).

    Returns:
        The scale factor (≤ 1); NaN, with ``qdot`` zeroed, when q̇ is not finite.
    """
    R, n = A.shape
    ratio = 0.0
    for k in range(n):
        acc = 0.0
        for i in range(R):
            acc += z[i] * A[i, k]
        qdot[k] = acc
        rel = abs(acc * inv_v_max[k])
        if not math.isfinite(rel):
            qdot[:] = 0.0
            return math.nan
        ratio = max(ratio, rel)
    scale = 1.0
    if ratio > 1.0:
        scale = 1.0 / ratio
        for k in range(n):
            qdot[k] *= scale
    return scale


def warm_up() -> None:
    """Load the compiled search into this process (from numba's cache, or compile it).

    That costs ~0.5 s from the cache (~20 s on a fresh install) and happens at the first call;
    :class:`~tpik.solver.TpikSolver` calls this when it is built, so that no control step — the
    first command to a real arm included — pays for it. Later calls return at once.
    """
    if not search_modes.signatures:  # nothing loaded in this process yet
        one, level = np.ones(1), np.zeros(1, dtype=np.int64)
        rows = np.ones((1, 1))
        search_modes(rows, one, one, level, np.zeros(1), one, False, True, True, True, False, 1.0, 1e-6, 1e-9, 6)
        rows.flags.writeable = False  # the solver passes its Jacobian rows read-only: a second signature
        search_modes(rows, one, one, level, np.zeros(1), one, False, True, True, True, False, 1.0, 1e-6, 1e-9, 6)

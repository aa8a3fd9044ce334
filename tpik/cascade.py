r"""The priority cascade and the search over active-set modes, in the row space of the tasks.

Let ``A`` stack every row a step can use (the equality rows of all levels and the row of every
candidate set-based task) and :math:`G = AA^T` (R × R). Each level's update is a combination of
its own rows and of the rows above it, so every velocity of the cascade is :math:`\dot q = A^Tz`
with :math:`z \in \mathbb{R}^R`; projections and inverses only need entries of ``G``:

* rows above a level: an incremental Cholesky factor ``L`` of :math:`G_{PP}` over an independent
  subset ``P`` of them (a row whose residual :math:`\|N a\|` is at or below the rank tolerance
  is skipped); the exact null-space projector of the augmented Jacobian (eqs. 5–6) applied to
  :math:`A_K^T y` is :math:`A_K^T y - A_P^T G_{PP}^{-1} G_{PK} y`;
* ``nsb`` (eq. 4), level K: :math:`\dot q_K = J_K^\# x_K`, i.e. :math:`y = (G_{KK}+\lambda^2I)^{-1}x_K`,
  then projected as above;
* ``ss``, level K: :math:`B = J_K N_{1,k-1}`, :math:`BB^T = G_{KK} - G_{KP}G_{PP}^{-1}G_{PK}`
  (a Schur complement), :math:`y = (BB^T + \lambda^2 I)^{-1}(x_K - G_{K\cdot}z)`, :math:`B^Ty`
  projected as above;
* a mode's checks: :math:`J_C\dot q = G_{C\cdot}z` (eqs. 8–9) and :math:`\|\dot q\|^2 = z^TGz`.

Only the chosen mode is mapped back to joint space. A level costs O(R²) float operations on
Python lists (R ≈ 6 in the paper's case 2): at these sizes that is cheaper than the fixed cost
of NumPy calls, and it lets the depth-first mode search share every prefix of the cascade.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from operator import mul

import numpy as np

from tpik.dls import backward, forward, gram_dls


@dataclass
class LevelRows:
    """One level at this step, as row indices into ``A``.

    Attributes:
        name: Level name.
        eq_rows: Rows of the level's equality tasks (always in).
        candidates: Global indices of the level's candidate set-based tasks.
    """

    name: str
    eq_rows: list[int]
    candidates: list[int]


@dataclass
class Mode:
    r"""A solved mode: which candidates are in, its coordinates ``z`` and checks.

    Attributes:
        mask: Bit ``c`` set when candidate ``c`` is inserted.
        z: Coordinates of q̇ on the rows of ``A``. Shape (R,).
        norm2: :math:`\|\dot q\|^2` [rad²/s²].
        n_active: Number of inserted candidates.
        damping: λ per level of :attr:`ModeSearch.levels`.
    """

    mask: int
    z: list[float]
    norm2: float
    n_active: int
    damping: tuple[float, ...]


_State = tuple[list[float], list[int], list[list[float]], tuple[float, ...]]
"""Cascade state after some levels: z, independent rows P above, Cholesky of G_PP, λ's."""


_Leaf = tuple[int, list[float], tuple[float, ...]]
"""A solved mode before its checks: mask, z, λ's."""


class ModeSearch:
    r"""Solve the modes of one control step and pick the best admissible one.

    Args:
        A: Stacked rows: equality rows and candidate rows, level by level. Shape (R, n).
        x: CLIK reference of every row [task unit/s]. Shape (R,).
        levels: Levels with at least one row or candidate, highest first.
        cand_row: Row index in ``A`` of each candidate.
        cand_side: +1 for a candidate past its upper activation threshold, −1 past its lower.
        ss: Siciliano–Slotine variant instead of NSB (eq. 4).
        velocity_norm_max: :math:`\|\dot q\|_{\max}` of the damping [rad/s].
        rank_tol: Rank tolerance on singular values.
        admissibility_tol: Slack on :math:`J_A\dot q` in eqs. 8–9 [task unit/s].
        largest_norm: Selection rule: largest norm first (else fewest active first).
    """

    def __init__(
        self,
        A: np.ndarray,
        x: list[float],
        levels: list[LevelRows],
        cand_row: list[int],
        cand_side: list[float],
        ss: bool,
        velocity_norm_max: float,
        rank_tol: float,
        admissibility_tol: float,
        largest_norm: bool,
    ) -> None:
        self.A = A
        self.G_np = A @ A.T
        self.G: list[list[float]] = self.G_np.tolist()
        self.g_finite = math.isfinite(sum(map(sum, self.G)))
        """Whether every entry of G is finite (NaN/inf anywhere in A shows here)."""
        self.x = x
        self.R = len(x)
        self.levels = levels
        self.cand_row = cand_row
        self.cand_side = cand_side
        self.n_cand = len(cand_row)
        self.full = (1 << self.n_cand) - 1
        self.ss = ss
        self.vnorm = velocity_norm_max
        self.tol = rank_tol
        self.tol2 = rank_tol * rank_tol
        self.adm_tol = admissibility_tol
        self.largest_norm = largest_norm
        self.level_bits = [sum(1 << c for c in level.candidates) for level in levels]
        self.evaluated = 0
        self._own: dict[tuple[int, int], tuple[list[int], list[float], float, list[float]]] = {}

    # ------------------------------------------------------------------ one level
    def _rows(self, li: int, mask: int) -> list[int]:
        """Rows of level ``li`` in the mode: equality rows, then the inserted candidates."""
        level = self.levels[li]
        chosen = [self.cand_row[c] for c in level.candidates if mask >> c & 1]
        return level.eq_rows + chosen if chosen else level.eq_rows

    def _own_solution(self, li: int, mask: int) -> tuple[list[int], list[float], float, list[float]]:
        r"""NSB: rows K, :math:`y = (G_{KK} + \lambda^2 I)^{-1} x_K`, λ and :math:`G_{\cdot K}\,y`.

        Cached per level subset: the NSB term of a level does not depend on the levels above.
        """
        key = (li, mask & self.level_bits[li])
        hit = self._own.get(key)
        if hit is None:
            G = self.G
            K = self._rows(li, mask)
            y, lam = gram_dls([[G[a][b] for b in K] for a in K], [self.x[k] for k in K], self.vnorm, self.tol)
            hit = (K, y, lam, [])  # G_{·K} y is filled in when a projection first needs it
            self._own[key] = hit
        return hit

    def _own_image(self, own: tuple[list[int], list[float], float, list[float]]) -> list[float]:
        r"""NSB: :math:`c = G_{\cdot K}\,y = A\,\dot q_K` of a cached own solution (computed once)."""
        K, y, _, c = own
        if not c:
            pairs = [(kb, yb) for kb, yb in zip(K, y, strict=True) if yb != 0.0]
            for Gj in self.G:
                acc = 0.0
                for kb, yb in pairs:
                    acc += Gj[kb] * yb
                c.append(acc)
        return c

    def _add_rows(self, P: list[int], L: list[list[float]], K: list[int]) -> tuple[list[int], list[list[float]]]:
        """Extend the independent rows P and the Cholesky factor of G_PP with the rows K."""
        G = self.G
        tol2 = self.tol2
        P2, L2 = list(P), list(L)
        for k in K:
            Gk = G[k]
            w: list[float] = []
            d = Gk[k]
            for j, Lj in enumerate(L2):  # forward substitution L w = G_Pk
                acc = Gk[P2[j]]
                for t in range(j):
                    acc -= Lj[t] * w[t]
                acc /= Lj[j]
                w.append(acc)
                d -= acc * acc
            if d > tol2:
                w.append(math.sqrt(d))
                L2.append(w)
                P2.append(k)
        return P2, L2

    def _advance(self, li: int, mask: int, state: _State, need_projector: bool) -> _State:
        """Add level ``li`` of mode ``mask`` to the cascade state."""
        z, P, L, lams = state
        if not (self.levels[li].eq_rows or mask & self.level_bits[li]):
            return z, P, L, (*lams, 0.0)
        G = self.G
        z2 = z.copy()
        if not self.ss:
            # NSB (eq. 4): q̇_K = J_K^# x_K = A_Kᵀ y, then projected on the null space above.
            own = self._own_solution(li, mask)
            K, y, lam, _ = own
            if P:
                c = self._own_image(own)
                g = forward(L, [c[p] for p in P])
            else:
                g = None
        else:
            # SS: B = J_K N, BBᵀ = G_KK − WᵀW with W = L⁻¹ G_PK; reference compensated.
            K = self._rows(li, mask)
            nz = [(j, zj) for j, zj in enumerate(z) if zj != 0.0]
            r = []
            for k in K:
                Gk = G[k]
                acc = self.x[k]
                for j, zj in nz:
                    acc -= Gk[j] * zj
                r.append(acc)
            if P:
                W = [forward(L, [G[p][k] for p in P]) for k in K]
                S = []
                for Wa, ka in zip(W, K, strict=True):
                    Gka = G[ka]
                    Sa = []
                    for Wb, kb in zip(W, K, strict=True):
                        acc = Gka[kb]
                        for wa, wb in zip(Wa, Wb, strict=True):
                            acc -= wa * wb
                        Sa.append(acc)
                    S.append(Sa)
            else:
                S = [[G[a][b] for b in K] for a in K]
            y, lam = gram_dls(S, r, self.vnorm, self.tol)
            g = None
            if P:
                g = [0.0] * len(P)
                for Wb, yb in zip(W, y, strict=True):
                    for t, wb in enumerate(Wb):
                        g[t] += wb * yb
        for yb, kb in zip(y, K, strict=True):
            z2[kb] += yb
        if g is not None:
            # Remove the part of A_Kᵀ y in the span of the rows above: A_Pᵀ G_PP⁻¹ G_PK y.
            u = backward(L, g)
            for up, p in zip(u, P, strict=True):
                z2[p] -= up
        if need_projector:
            P, L = self._add_rows(P, L, K)
        return z2, P, L, (*lams, lam)

    # ------------------------------------------------------------------ modes
    def cascade(self, mask: int) -> _Leaf:
        """Solve one mode through every level."""
        state: _State = ([0.0] * self.R, [], [], ())
        last = len(self.levels) - 1
        for li in range(len(self.levels)):
            state = self._advance(li, mask, state, li < last)
        self.evaluated += 1
        return mask, state[0], state[3]

    def _select(self, leaves: list[_Leaf], incumbent: Mode | None = None) -> Mode | None:
        """Check the leaves (finite, eqs. 8–9) and return the best of them and ``incumbent``."""
        if len(leaves) <= 64:
            return self._select_small(leaves, incumbent)
        Z = np.array([leaf[1] for leaf in leaves])
        GZ = Z @ self.G_np
        norms = (Z * GZ).sum(axis=1).tolist()
        moves = None
        if self.n_cand:  # J_C q̇, signed so that "further out" is positive
            moves = (GZ[:, self.cand_row] * np.array(self.cand_side)).tolist()
        adm_tol, n_cand = self.adm_tol, self.n_cand
        best = incumbent
        for i, (mask, z, lams) in enumerate(leaves):
            norm2 = norms[i]
            if not math.isfinite(norm2):
                continue
            mode = Mode(mask, z, norm2, mask.bit_count(), lams)
            if not self.better(mode, best):
                continue
            if moves is not None and mask != self.full:
                row = moves[i]
                if any(row[c] > adm_tol and not mask >> c & 1 for c in range(n_cand)):
                    continue  # a left-out task would move further out (eqs. 8–9)
            best = mode
        return best

    def _select_small(self, leaves: list[_Leaf], incumbent: Mode | None) -> Mode | None:
        """:meth:`_select` in plain floats (faster than NumPy calls for a few small leaves)."""
        G, adm_tol, full, g_finite = self.G, self.adm_tol, self.full, self.g_finite
        cands = list(enumerate(zip(self.cand_row, self.cand_side, strict=True)))
        best = incumbent
        for mask, z, lams in leaves:
            # Gz, then ‖q̇‖² = zᵀGz and J_C q̇ = (Gz)_C. With G finite, zero entries of z add 0.
            if g_finite:
                gz = [sum(map(mul, Gi, z)) for Gi in G]
                norm2 = sum(map(mul, z, gz))
            else:  # G overflowed: skip the zero entries of z (inf · 0 would give NaN)
                nz = [(j, zj) for j, zj in enumerate(z) if zj != 0.0]
                gz = []
                for Gi in G:
                    acc = 0.0
                    for j, zj in nz:
                        acc += Gi[j] * zj
                    gz.append(acc)
                norm2 = 0.0
                for i, zi in nz:
                    norm2 += zi * gz[i]
            if not math.isfinite(norm2):
                continue
            n_active = mask.bit_count()
            if best is not None:
                # Inline of better(): skip the Mode object for a leaf that loses.
                b2 = best.norm2
                close = abs(norm2 - b2) <= 1e-12 * (1.0 + max(norm2, b2))
                if self.largest_norm:
                    wins = n_active < best.n_active if close else norm2 > b2
                elif n_active != best.n_active:
                    wins = n_active < best.n_active
                else:
                    wins = norm2 > b2 and not close
                if not wins:
                    continue
            if mask != full:
                outward = False
                for c, (row, side) in cands:
                    if not mask >> c & 1:
                        if gz[row] * side > adm_tol:
                            outward = True  # a left-out task would move further out (eqs. 8–9)
                            break
                if outward:
                    continue
            best = Mode(mask, z, norm2, n_active, lams)
        return best

    def better(self, a: Mode, b: Mode | None) -> bool:
        """Whether ``a`` beats ``b`` under the selection rule (ties within 1e-12 relative)."""
        if b is None:
            return True
        close = abs(a.norm2 - b.norm2) <= 1e-12 * (1.0 + max(a.norm2, b.norm2))
        if self.largest_norm:
            return a.n_active < b.n_active if close else a.norm2 > b.norm2
        if a.n_active != b.n_active:
            return a.n_active < b.n_active
        return a.norm2 > b.norm2 and not close

    def single(self, mask: int) -> Mode:
        """The mode ``mask`` alone, unchecked (its norm is not computed: NaN)."""
        mask, z, lams = self.cascade(mask)
        return Mode(mask, z, math.nan, mask.bit_count(), lams)

    def exhaustive(self) -> Mode | None:
        """All 2^|C| modes, depth-first over the levels so shared prefixes are solved once."""
        levels = self.levels
        last = len(levels) - 1
        subsets: list[list[int]] = []
        for level in levels:
            masks = [0]
            for c in level.candidates:
                masks += [m | 1 << c for m in masks]
            subsets.append(masks)
        leaves: list[_Leaf] = []
        if not self.ss:
            self._explore_nsb(subsets, leaves)
            self.evaluated += len(leaves)
            return self._select(leaves)

        def explore(li: int, mask: int, state: _State) -> None:
            for sub in subsets[li]:
                m = mask | sub
                child = self._advance(li, m, state, li < last)
                if li < last:
                    explore(li + 1, m, child)
                else:
                    leaves.append((m, child[0], child[3]))

        explore(0, 0, ([0.0] * self.R, [], [], ()))
        self.evaluated += len(leaves)
        return self._select(leaves)

    def _explore_nsb(self, subsets: list[list[int]], leaves: list[_Leaf]) -> None:
        r"""NSB depth-first enumeration: :meth:`_advance` inlined, same arithmetic in the same order.

        A level's own solution and its image :math:`G_{\cdot K}y` do not depend on the levels
        above (NSB), so they are formed once per (level, subset) before the enumeration.
        """
        levels = self.levels
        last = len(levels) - 1
        R = self.R
        # Per level and subset: (subset bits, (y_k, k) pairs or None for an empty level, λ, G_{·K}y, K).
        table: list[list[tuple[int, list[tuple[float, int]] | None, float, list[float], list[int]]]] = []
        for li, level in enumerate(levels):
            row = []
            for sub in subsets[li]:
                if not (level.eq_rows or sub):
                    row.append((sub, None, 0.0, [], []))
                    continue
                own = self._own_solution(li, sub)
                K, y, lam, _ = own
                c = self._own_image(own) if li > 0 else []
                row.append((sub, list(zip(y, K, strict=True)), lam, c, K))
            table.append(row)
        add_rows = self._add_rows

        def explore(li: int, mask: int, z: list[float], P: list[int], L: list[list[float]], lams: tuple) -> None:
            is_last = li == last
            for sub, yk, lam, c, K in table[li]:
                m = mask | sub
                if yk is None:
                    z2, P2, L2, lams2 = z, P, L, (*lams, 0.0)
                else:
                    z2 = z.copy()
                    for yb, kb in yk:
                        z2[kb] += yb
                    if P:
                        u = backward(L, forward(L, [c[p] for p in P]))
                        for up, p in zip(u, P, strict=True):
                            z2[p] -= up
                    lams2 = (*lams, lam)
                    if is_last:
                        P2, L2 = P, L
                    else:
                        P2, L2 = add_rows(P, L, K)
                if is_last:
                    leaves.append((m, z2, lams2))
                else:
                    explore(li + 1, m, z2, P2, L2, lams2)

        explore(0, 0, [0.0] * R, [], [], ())

    def greedy(self) -> Mode | None:
        """Greedy release from S = C: drop the task whose removal gives the best admissible mode."""
        current = self._select([self.cascade(self.full)])
        while current is not None and current.mask:
            removals = [self.cascade(current.mask & ~(1 << c)) for c in range(self.n_cand) if current.mask >> c & 1]
            step = self._select(removals)
            if step is None or not self.better(step, current):
                break
            current = step
        return current

    def velocity(self, mode: Mode) -> np.ndarray:
        r"""Joint velocity :math:`\dot q = A^T z` of a mode [rad/s]. Shape (n,)."""
        return np.array(mode.z) @ self.A

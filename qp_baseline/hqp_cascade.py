r"""The levels of one control step solved in priority order (a lexicographic cascade).

After level :math:`k`, its set rows are relaxed by their optimal slack :math:`w_k^*` (plus a
margin δ where relaxed, so the later feasible sets keep an interior) and its equality rows are
eliminated for the levels below: :math:`Z` becomes an orthonormal basis of
:math:`\{Z z : J_k Z z = 0\}` (SVD, relative rank tolerance ``rank_tolerance``); a level whose
null space is empty is not solved at all. After the last task level, the min-norm level
:math:`\min\|\dot q\|^2` fixes the remaining freedom when ``min_norm_level`` is on and a backend
was called (without a backend answer q̇ is already the exact ε-regularised minimum-norm solution).

A level without a usable answer is *given up*: level 0 fails the step, a later level keeps the
solution of the levels above it (DEGRADED, it and every level below counted as dropped). A kept
answer that is not certified makes the step DEGRADED (FAILED at level 0). The min-norm level
only picks among equally good answers: its failures are noted, never degrading.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from qp_baseline.cascade_kernels import zero_feasible
from qp_baseline.exceptions import NoSolutionFound
from qp_baseline.hqp_layout import HierarchyLayout
from qp_baseline.hqp_level import CascadeLevel
from qp_baseline.hqp_level_solve import LevelOutcome, LevelSolver
from qp_baseline.hqp_settings import CascadeSettings
from tpik.step_result import SolveStatus


@dataclass
class CascadeState:
    """Running state of one step's cascade: q̇ so far, relaxed bounds, null space, counters.

    Attributes:
        qd: q̇ of the levels solved so far. Shape (n,).
        h_rel: Set-row bounds relaxed by the solved levels' slacks. Shape (m,).
        lb: Lower bounds of the hard box (composed limits). Shape (n,).
        ub: Upper bounds of the hard box. Shape (n,).
        cuts: The set rows of level k are ``cuts[k]:cuts[k + 1]``.
        Z: Null-space basis of the solved equality rows; None: the identity. Shape (n, d).
        slack: Optimal slack per row, set by the first backend answer. Shape (m,).
        residuals: ‖J q̇ − r‖ per level name.
        iterations: Backend iterations per level name, where reported.
        qp_calls: Levels that called the backend.
        retries: Levels answered by the retry.
        levels_dropped: Task levels given up (the failed one and every level below).
        levels_uncertified: Levels whose answer was kept without a certificate.
        status: OK or DEGRADED so far.
        message: What went wrong so far.
        min_norm_failure: Why the min-norm level failed or was not certified (empty: it did not).
    """

    qd: np.ndarray
    h_rel: np.ndarray
    lb: np.ndarray
    ub: np.ndarray
    cuts: list[int]
    Z: np.ndarray | None = None
    slack: np.ndarray | None = None
    residuals: dict[str, float] = field(default_factory=dict)
    iterations: dict[str, int] = field(default_factory=dict)
    qp_calls: int = 0
    retries: int = 0
    levels_dropped: int = 0
    levels_uncertified: int = 0
    status: SolveStatus = SolveStatus.OK
    message: str = ""
    min_norm_failure: str = ""

    def add_message(self, method: str, note: str) -> None:
        """Append ``note`` to the message (which starts with the method's name)."""
        self.message = f"{self.message}; {note}" if self.message else f"{method}: {note}"


class LevelFailure(NamedTuple):
    """Why the step fails: level 0 had no usable or no certified answer."""

    message: str
    level: int


class Cascade:
    """The levels of one step, in priority order (module docstring).

    Args:
        layout: The hierarchy's rows, evaluated for this step.
        settings: The cascade's settings.
        levels: Solves each level.
        method: Method name (in the messages).
    """

    def __init__(self, layout: HierarchyLayout, settings: CascadeSettings, levels: LevelSolver, method: str) -> None:
        self.layout = layout
        self.settings = settings
        self.levels = levels
        self.method = method
        self.n_levels = len(layout.levels)

    def level_name(self, k: int) -> str:
        """Name of level ``k`` (``"min_norm"`` for the min-norm level)."""
        return self.layout.levels[k].name if k < self.n_levels else "min_norm"

    def run(self, state: CascadeState) -> LevelFailure | None:
        """Solve the levels in priority order into ``state``; why the step fails, or None."""
        for k in range(self._first_level(state), self.n_levels + 1):
            lv = self._level(k, state)
            if lv is None:
                break
            if lv.d == 0 or (lv.r.size == 0 and lv.c0 == lv.c1):
                continue
            try:
                outcome = self.levels.solve(lv)
            except NoSolutionFound as exc:
                if k == 0:
                    return LevelFailure(f"{self.method}: {exc}", k)
                self._give_up(state, k, exc)
                break
            state.qd = outcome.qdot
            if outcome.doubt:
                if k == 0:
                    return LevelFailure(f"{self.method}: priority level 0: answer not certified: {outcome.doubt}", k)
                self._note_doubt(state, k, outcome.doubt)
            self._after_level(state, lv, outcome)
        return None

    def _first_level(self, state: CascadeState) -> int:
        """Where the cascade starts: after leading levels of set tasks only that q̇ = 0 solves.

        Zero is their regularised optimum when it is feasible: inside the box and every such row
        has h ≥ 0 (the fast path of ``unconstrained_first``).
        """
        if not self.settings.options.unconstrained_first:
            return 0
        first_eq = self.layout.first_eq
        c_pre = state.cuts[first_eq]
        if first_eq and zero_feasible(state.lb, state.ub, state.h_rel[:c_pre]):
            return first_eq
        return 0

    def _level(self, k: int, state: CascadeState) -> CascadeLevel | None:
        """Level ``k`` as the cascade poses it now; None: the cascade ends before it.

        The min-norm level (k = number of task levels) is min ‖q̇‖² under all rows. Its optimum
        sits on the constraints of the levels above: a margin δ gives the feasible set an
        interior (ProxQP reports "infeasible" without it).
        """
        eps, G, h, cuts = self.settings.options.regularization, self.layout.G, state.h_rel, state.cuts
        if k < self.n_levels:
            J, r = self.layout.levels[k].J, self.layout.levels[k].r
            return CascadeLevel(k, state.qd, state.Z, J, r, G, h, cuts[k], cuts[k + 1], state.lb, state.ub, eps, 0.0)
        if self.settings.min_norm_level and state.qp_calls:
            J, r, margin = self.levels.builder.eye, self.levels.builder.zeros, self.settings.slack_margin
            return CascadeLevel(
                k, state.qd, state.Z, J, r, G, h, cuts[k], cuts[k], state.lb, state.ub, eps, margin, True
            )
        return None

    def _give_up(self, state: CascadeState, k: int, exc: NoSolutionFound) -> None:
        """Level ``k`` > 0 had no usable answer: keep the solution of the levels above it."""
        if k == self.n_levels:
            state.min_norm_failure = str(exc)  # it only picks among equally good answers
            return
        state.status = SolveStatus.DEGRADED
        state.levels_dropped = self.n_levels - k
        state.message = f"{self.method}: {exc}; kept the solution of the levels above ({state.levels_dropped} dropped)"

    def _note_doubt(self, state: CascadeState, k: int, doubt: str) -> None:
        """Level ``k`` > 0 kept an uncertified answer: DEGRADED (the min-norm level: noted only)."""
        if k == self.n_levels:
            state.min_norm_failure = f"answer not certified: {doubt}"  # kept: it meets every level above
            return
        state.status = SolveStatus.DEGRADED
        state.levels_uncertified += 1
        state.add_message(self.method, f"priority level {k} ({self.level_name(k)}): answer not certified: {doubt}")

    def _after_level(self, state: CascadeState, lv: CascadeLevel, outcome: LevelOutcome) -> None:
        """Book-keeping after a level: counters, relaxed rows, residual, the next null space."""
        k, c0, c1 = lv.k, lv.c0, lv.c1
        state.qp_calls += outcome.backend_calls
        state.retries += outcome.retried
        if outcome.iterations is not None:
            state.iterations[self.level_name(k)] = outcome.iterations
        if outcome.backend_calls and c1 > c0:
            # This level's slack at its own optimum relaxes its rows for every later level; a
            # relaxed row sits on the best value reachable, so it gets a margin δ: without it
            # the later feasible set has no interior and quadprog and the interior-point
            # backends report it infeasible.
            w = self.layout.G[c0:c1] @ state.qd
            w -= state.h_rel[c0:c1]
            np.maximum(w, 0.0, out=w)
            if state.slack is None:
                state.slack = np.zeros(state.h_rel.shape[0])
            state.slack[c0:c1] = w
            state.h_rel[c0:c1] += w + self.settings.slack_margin * (w > 0.0)
        if lv.r.size and k < self.n_levels:
            res = lv.J @ state.qd - lv.r
            state.residuals[self.layout.levels[k].name] = math.sqrt(float(res @ res))  # np.linalg.norm's own sum
            if k + 1 < self.n_levels or (self.settings.min_norm_level and state.qp_calls):
                state.Z = self._null_space(lv.J, state.Z)

    def _null_space(self, J: np.ndarray, Z: np.ndarray | None) -> np.ndarray:
        """Orthonormal basis of {Z z : J Z z = 0} (Z = I when None). Shape (n, d')."""
        M = J if Z is None else J @ Z
        _, s, Vt = np.linalg.svd(M, full_matrices=True)
        top = float(s[0]) if s.size else 0.0
        rank = int(np.count_nonzero(s > self.settings.options.rank_tolerance * max(1.0, top)))
        basis = Vt[rank:].T
        return basis if Z is None else Z @ basis

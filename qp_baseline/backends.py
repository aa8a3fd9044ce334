"""One record per QP backend: what the HQP cascade, the mink peer and the benches need to know of it.

Everything backend-specific lives here (settings, retry, tolerance, the final min-norm level, warm
start, matrix format, its quirks and the glue they need, its time-limit argument); the solvers read
the record by the backend's name and hold no table or branch of their own.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import piqp
from proxsuite import proxqp


@dataclass(frozen=True)
class QpBackend:
    """A QP backend as qpsolvers names it, and how the project uses it.

    Attributes:
        name: qpsolvers' name.
        defaults: Settings every solve starts from; user settings override them key by key.
        retry: Settings of the one retry after a failed or rejected answer (the Hessian then
            gets :data:`qp_baseline.hqp_attempts.RETRY_REGULARIZATION` more on its diagonal).
        tolerance: Accepted constraint violation of an answer [rad/s or m/s].
        min_norm_level: Whether the cascade's final min-norm level is solved by default
            (inexact backends need it).
        warm_start: Whether each level starts from its previous-step answer by default.
        sparse: The backend takes CSC matrices (qpsolvers converts, and warns, otherwise).
        warns_on_failure: qpsolvers warns when it fails (silenced: failures are reported in the step).
        prints: The C library prints to stdout whatever ``verbose`` says (silenced).
        time_limit_key: The backend's own wall-clock time-limit argument, or None.
        enum_settings: Settings whose value may be given as the name of a member of the
            backend's enum: setting name → a function giving the members by name.
        setting_names: For a backend that accepts unknown setting names silently, a function
            giving the names it knows (unknown ones are rejected against them); None otherwise.
    """

    name: str
    defaults: Mapping[str, Any] = field(default_factory=dict)
    retry: Mapping[str, Any] = field(default_factory=dict)
    tolerance: float = 1e-6
    min_norm_level: bool = False
    warm_start: bool = False
    sparse: bool = False
    warns_on_failure: bool = False
    prints: bool = False
    time_limit_key: str | None = None
    enum_settings: Mapping[str, Callable[[], Mapping[str, Any]]] = field(default_factory=dict)
    setting_names: Callable[[], frozenset[str]] | None = None


def _proxqp_initial_guesses() -> Mapping[str, Any]:
    """ProxQP's ``InitialGuess`` members by name."""
    members: Mapping[str, Any] = proxqp.InitialGuess.__members__
    return members


def _piqp_setting_names() -> frozenset[str]:
    """The names of PIQP's settings (it ignores unknown names silently)."""
    return frozenset(a for a in dir(piqp.DenseSolver().settings) if not a.startswith("_"))


BACKENDS: dict[str, QpBackend] = {
    # Active-set solvers: exact on their active set, defaults are fine (near-singular Hessians are
    # the regularisation's business). DAQP's retry: proximal-point iterations for near-singular
    # Hessians (they converge to the optimum of the QP as posed): on 3 of the 200 random bench
    # states DAQP reported level 2 unsolvable without.
    "daqp": QpBackend("daqp", retry={"eps_prox": 1e-6}, time_limit_key="time_limit"),
    "quadprog": QpBackend("quadprog", warns_on_failure=True),
    # OSQP (docs/benchmarks.md, "QP backends: timing vs correctness"): its defaults (eps 1e-3, no
    # polish) leave violations of ~1e-3. eps 1e-6 with eps_rel 0 (absolute: the rows are in rad/s and
    # m/s), polishing with 10 refinement steps; no duality-gap termination test (OSQP 1.x's absolute
    # gap test kept it iterating to max_iter on most level QPs: the certificate checks the gap
    # itself); infeasibility detection effectively off (eps_prim_inf 1e-9: every level QP is
    # feasible by construction, and at 1e-4 OSQP declared feasible QPs infeasible); 2000
    # iterations. A looser retry converges where that ran out of iterations; the tolerance still
    # checks it. OSQP prints "Polishing not needed" whatever ``verbose``.
    "osqp": QpBackend(
        "osqp",
        defaults={
            "eps_abs": 1e-6,
            "eps_rel": 0.0,
            "polish": True,
            "polish_refine_iter": 10,
            "check_dualgap": False,
            "eps_prim_inf": 1e-9,
            "max_iter": 2000,
        },
        retry={"eps_abs": 1e-9, "eps_rel": 0.0, "max_iter": 4000},
        min_norm_level=True,
        sparse=True,
        warns_on_failure=True,
        prints=True,
        time_limit_key="time_limit",
    ),
    # ProxQP's default eps_abs is 1e-3 (qpsolvers documentation). Its default equality-constrained
    # initial guess ends in PROXQP_PRIMAL_INFEASIBLE on many of the (feasible) level QPs. It does not
    # test the duality gap by default, so a "solved" answer may be suboptimal: the certificate
    # catches those (retry or KKT polish); check_duality_gap = true costs ~50x the iterations here.
    # Its retry solves the closest feasible problem instead of a false infeasibility; the
    # project's own feasibility check decides (every level QP is feasible by construction).
    "proxqp": QpBackend(
        "proxqp",
        defaults={"eps_abs": 1e-9, "eps_rel": 0.0, "initial_guess": "NO_INITIAL_GUESS"},
        retry={
            "eps_abs": 1e-7,
            "eps_rel": 0.0,
            "max_iter": 100000,
            "initial_guess": "NO_INITIAL_GUESS",
            "primal_infeasibility_solving": True,
        },
        min_norm_level=True,
        enum_settings={"initial_guess": _proxqp_initial_guesses},
    ),
    "clarabel": QpBackend(
        "clarabel",
        defaults={"tol_feas": 1e-9, "tol_gap_abs": 1e-9, "tol_gap_rel": 1e-9},
        retry={"tol_feas": 1e-7, "tol_gap_abs": 1e-7, "tol_gap_rel": 1e-7, "max_iter": 500},
        min_norm_level=True,
        sparse=True,
        warns_on_failure=True,
        time_limit_key="time_limit",
    ),
    "piqp": QpBackend(
        "piqp",
        defaults={"eps_abs": 1e-9, "eps_rel": 0.0},
        retry={"eps_abs": 1e-7, "eps_rel": 0.0, "max_iter": 1000},
        min_norm_level=True,
        setting_names=_piqp_setting_names,
    ),
}
"""The backends the project is tested with, in the order they are listed to users. Warm start is
off for every one: only OSQP and ProxQP take a start point through qpsolvers (the primal x alone: a
new solver object, rho, duals and factorisation every call), and it did not pay consistently (on
an 80-step closed-loop rollout with a wall binding OSQP took 206 975 iterations warm vs 174 950
cold, 158 975 vs 190 950 once the KKT polish changed which levels retry; docs/benchmarks.md);
``warm_start = true`` tries it."""

SUPPORTED_SOLVERS: tuple[str, ...] = tuple(BACKENDS)
"""QP backends this package is tested with."""

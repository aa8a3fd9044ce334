"""How a QP reaches a backend through qpsolvers, for the HQP cascade and the mink peer.

Everything here reads the backend's record (:data:`qp_baseline.backends.BACKENDS`): which
backends are usable, settings as the backend takes them, a problem in the matrix format it
takes, its warnings and C-level prints silenced, a setting it rejects caught before the first
step, its iteration count read back.
"""

from __future__ import annotations

import contextlib
import os
import re
import sys
import warnings
from collections.abc import Iterator, Mapping
from typing import Any

import numpy as np
import qpsolvers
import scipy.sparse as spa

from qp_baseline.backends import BACKENDS, SUPPORTED_SOLVERS
from qp_baseline.exceptions import InvalidSettings, UnknownSolver
from qp_baseline.qp_problem import DenseProblem, without_empty_rows


def available_qp_solvers() -> list[str]:
    """Backends usable here: the supported ones (:mod:`qp_baseline.backends`) that qpsolvers has installed."""
    installed = set(qpsolvers.available_solvers)
    return [name for name in SUPPORTED_SOLVERS if name in installed]


def check_solver(solver: str) -> None:
    """Raise :class:`UnknownSolver` (listing the usable ones) unless ``solver`` is usable here."""
    if solver not in available_qp_solvers():
        raise UnknownSolver(solver, available_qp_solvers())


def backend_kwargs(solver: str, settings: Mapping[str, Any]) -> dict[str, Any]:
    """Settings as the backend takes them: a name given for an enum setting becomes its member.

    Raises:
        InvalidSettings: The name is not a member of the setting's enum.
    """
    kwargs = dict(settings)
    for key, members_of in BACKENDS[solver].enum_settings.items():
        value = kwargs.get(key)
        if isinstance(value, str):
            names = members_of()
            if value not in names:
                raise InvalidSettings(solver, f"setting '{key}' must be one of {', '.join(names)}, got {value!r}")
            kwargs[key] = names[value]
    return kwargs


def backend_problem(problem: DenseProblem, solver: str) -> qpsolvers.Problem:
    """``problem`` as ``solver`` takes it: no empty rows; CSC matrices for a sparse backend."""
    plain = without_empty_rows(problem)
    if BACKENDS[solver].sparse:
        plain.P = spa.csc_matrix(plain.P)
        if plain.G is not None:
            plain.G = spa.csc_matrix(plain.G)
        if plain.A is not None:
            plain.A = spa.csc_matrix(plain.A)
    return plain


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


def solve_quietly(problem: qpsolvers.Problem, solver: str, quiet: bool, **kwargs: Any) -> qpsolvers.Solution:
    """``qpsolvers.solve_problem`` without the failure warnings (failures are reported in StepResult).

    ``quiet`` also silences the C library's stdout (the backend's ``prints``).
    """
    if not BACKENDS[solver].warns_on_failure:
        return qpsolvers.solve_problem(problem, solver=solver, **kwargs)
    with warnings.catch_warnings(), _quiet_stdout(quiet):
        warnings.simplefilter("ignore")
        return qpsolvers.solve_problem(problem, solver=solver, **kwargs)


def probe_settings(solver: str, settings: Mapping[str, Any]) -> None:
    """Fail early on a backend setting the backend rejects.

    A two-variable QP is solved with ``settings``; an exception of the backend, or a failure on
    this trivial problem, becomes :class:`InvalidSettings`, naming the setting when the backend's
    message does. A backend that ignores unknown names has them checked against the names it
    knows (its record's ``setting_names``).

    Raises:
        UnknownSolver: ``solver`` is not available.
        InvalidSettings: A setting is unknown or unusable.
    """
    check_solver(solver)
    names_of = BACKENDS[solver].setting_names
    if names_of is not None:
        known = names_of()
        for key in settings:
            if key not in known:
                raise InvalidSettings(solver, f"unknown setting '{key}'; known: {', '.join(sorted(known))}", key)
    problem = DenseProblem(np.eye(2), np.array([-1.0, -1.0]), np.array([[1.0, 1.0]]), np.ones(1))
    try:
        solution = solve_quietly(
            backend_problem(problem, solver), solver, BACKENDS[solver].prints, **backend_kwargs(solver, settings)
        )
    except Exception as exc:  # noqa: BLE001 - whatever the backend raises is a settings error here
        bad_key = next((k for k in settings if re.search(rf"\b{re.escape(k)}\b", str(exc))), None)
        named = f"setting '{bad_key}'" if bad_key else f"settings {dict(settings)}"
        raise InvalidSettings(solver, f"{named} rejected by the backend: {exc}", bad_key) from exc
    if not solution.found or solution.x is None or not np.allclose(solution.x, [0.5, 0.5], atol=1e-3):
        raise InvalidSettings(solver, f"settings {dict(settings)} make the backend fail on a trivial QP")


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

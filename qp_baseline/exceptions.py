"""Errors of the hierarchical-QP baseline and the mink peer: one root, :class:`HqpError`.

A bad solver setting raises :class:`tpik.exceptions.InvalidSettings`, the one settings error of
every solver (re-exported here), which derives from ``TpikError`` and ``ValueError``.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from tpik.exceptions import InvalidSettings


class HqpError(Exception):
    """Root of every error raised by :mod:`qp_baseline`."""


class UnknownSolver(HqpError, ValueError):
    """The QP solver name is not supported or not installed; the message lists what is.

    Attributes:
        name: The rejected name.
        available: Names that would have been accepted.
    """

    def __init__(self, name: str, available: Sequence[str]) -> None:
        self.name = name
        self.available = tuple(available)
        listed = ", ".join(self.available) or "none installed"
        super().__init__(f"unknown QP solver '{name}'; available: {listed}")


class NoSolutionFound(HqpError):
    """A priority level of the cascade could not be solved.

    The data of the failure is kept for the caller (pink's ``NoSolutionFound`` idea):
    which level, and whatever the backend returned.

    Attributes:
        level: 0-based index of the priority level that failed.
        solution: The backend's answer (a :class:`qpsolvers.Solution`, or ``None`` when
            the backend raised).
        reason: Human-readable cause.
        certificate: Certificate of the last rejected answer (a
            :class:`qp_baseline.certificate.Certificate`), or ``None``.
    """

    def __init__(self, level: int, solution: Any, reason: str, certificate: Any = None) -> None:
        self.level = level
        self.solution = solution
        self.reason = reason
        self.certificate = certificate
        super().__init__(f"priority level {level}: {reason}")


__all__ = ["HqpError", "InvalidSettings", "NoSolutionFound", "UnknownSolver"]

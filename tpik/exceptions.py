"""Errors raised by the task framework and the analytic solver; :class:`TpikError` is the root."""

from __future__ import annotations

from robots.exceptions import UnknownFrame


class TpikError(Exception):
    """Root of every error raised by :mod:`tpik`."""


class TaskDefinitionError(TpikError, ValueError):
    """A task or hierarchy is built with invalid parameters (names the parameter and value)."""


class ThresholdOrderError(TaskDefinitionError):
    """Set-based task thresholds are not ordered σ_m < σ_{s,l} < σ_{a,l} < σ_{a,u} < σ_{s,u} < σ_M."""

    def __init__(self, task: str, lower_name: str, lower: float, upper_name: str, upper: float) -> None:
        super().__init__(
            f"task '{task}': thresholds out of order: {lower_name}={lower:g} must be < {upper_name}={upper:g}"
        )
        self.task = task


class TargetNotSet(TpikError):
    """An equality task is evaluated before its target was set."""

    def __init__(self, task: str) -> None:
        super().__init__(f"task '{task}' has no target: call set_target() first")
        self.task = task


class InvalidTaskState(TpikError, ValueError):
    """A task returned a value or Jacobian of the wrong shape or with non-finite entries."""


class EmptyHierarchy(TaskDefinitionError):
    """A hierarchy or one of its levels holds no task."""


class InvalidSettings(TpikError, ValueError):
    """A solver setting is unknown or has an unusable value; the message names it.

    The one settings error of every solver: TPIK's (:class:`tpik.solver.TpikSettings`), the HQP
    cascade's and its QP backends', and the mink peer's (:mod:`qp_baseline` re-exports it).

    ``InvalidSettings(solver, message, key)`` prefixes the message with the solver;
    ``InvalidSettings(message)`` is for a message that already says whose setting it is.

    Attributes:
        solver: Solver (``"tpik"``, a QP backend name, ``"mink"``) the settings were meant for,
            or ``None`` when the message alone says it.
        key: The offending setting, when it is known.
    """

    def __init__(self, solver: str, message: str | None = None, key: str | None = None) -> None:
        if message is None:
            self.solver: str | None = None
            text = solver
        else:
            self.solver = solver
            text = f"{solver}: {message}"
        self.key = key
        super().__init__(text)


__all__ = [
    "EmptyHierarchy",
    "InvalidSettings",
    "InvalidTaskState",
    "TargetNotSet",
    "TaskDefinitionError",
    "ThresholdOrderError",
    "TpikError",
    "UnknownFrame",
]

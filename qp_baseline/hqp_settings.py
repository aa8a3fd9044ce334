"""Settings of the HQP cascade: the user's options, and the same with every backend default filled in."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import Any

from qp_baseline.backends import QpBackend
from qp_baseline.certificate import Tolerances
from qp_baseline.exceptions import InvalidSettings
from robots import Robot
from tpik.limits import Limit, PositionLimit, VelocityLimit


def default_limits(robot: Robot) -> tuple[Limit, ...]:
    r"""HQP's hard box: the robot's velocity limits, then its position limits over one step.

    Composed in this order (:func:`tpik.limits.compose_box`) the box is
    :math:`\max(-v_{max}, (q_{min} - q)/dt) \le \dot q \le \min(v_{max}, (q_{max} - q)/dt)`, the
    position part clipped into :math:`[-v_{max}, v_{max}]` so that it is never empty.
    """
    return (VelocityLimit.from_robot(robot), PositionLimit.from_robot(robot))


@dataclass(frozen=True)
class HqpSettings:
    r"""Options of the cascade itself; every other setting goes to the QP backend.

    Attributes:
        regularization: ε of :math:`\epsilon\|\dot q\|^2` on every task level (unitless, > 0).
        tolerance: Accepted constraint violation of a backend answer [rad/s or m/s]; the
            backend's tolerance (:data:`qp_baseline.backends.BACKENDS`) when None.
        slack_tolerance: A slack above this makes the step DEGRADED; a row within it of its bound
            is reported binding (active set) [task unit / s]. ``max(1e-6, tolerance)`` when None.
        rank_tolerance: Relative singular-value threshold of the null-space bases.
        unconstrained_first: Skip the backend when a level's unconstrained minimiser is feasible.
        min_norm_level: Solve the final min-norm level; the backend's default
            (:data:`qp_baseline.backends.BACKENDS`) when None.
        retry: Retry a failed level once with its backend's retry settings (:data:`qp_baseline.backends.BACKENDS`).
        gain_cap: Cap every task gain at 1/dt in the control reference (:mod:`tpik.reference`;
            the same default as TPIK and mink).
        certify: Judge every backend answer by its certificate (:mod:`qp_baseline.certificate`:
            primal residual, dual residual, duality gap, level objective against the dual bound);
            off: status, constraints and the known feasible point only (the checks before the certificate existed).
        objective_tolerance: Accepted error of a level's residual norm, relative to 1 + ρ
            (:attr:`~qp_baseline.certificate.Tolerances.level`); ``max(1e-6, tolerance)`` when None.
        warm_start: Start each level's backend from that level's answer at the previous step;
            the backend's default (off for every backend) when None.
        kkt_polish: When a backend answer is not certified, polish it (:func:`qp_baseline.polish.polish`:
            exact KKT solves of the active set the answer identifies) and keep the polished answer if
            it is certified — OSQP's polishing idea, for every backend (one small least squares).
            Not OSQP's own ``polish`` setting, which goes to OSQP.
    """

    regularization: float = 1e-9
    tolerance: float | None = None
    slack_tolerance: float | None = None
    rank_tolerance: float = 1e-9
    unconstrained_first: bool = True
    min_norm_level: bool | None = None
    retry: bool = True
    gain_cap: bool = True
    certify: bool = True
    objective_tolerance: float | None = None
    warm_start: bool | None = None
    kkt_polish: bool = True

    def check(self, solver: str) -> None:
        """Raise :class:`InvalidSettings` naming the first bad value."""
        for key in ("regularization", "slack_tolerance", "rank_tolerance", "tolerance", "objective_tolerance"):
            value = getattr(self, key)
            if value is None and key in ("tolerance", "slack_tolerance", "objective_tolerance"):
                continue
            number = isinstance(value, int | float) and not isinstance(value, bool)
            if not (number and math.isfinite(value) and value > 0):
                raise InvalidSettings(solver, f"setting '{key}' must be a finite number > 0, got {value!r}", key)
        for key in (
            "unconstrained_first",
            "min_norm_level",
            "retry",
            "gain_cap",
            "certify",
            "warm_start",
            "kkt_polish",
        ):
            value = getattr(self, key)
            if not (isinstance(value, bool) or (value is None and key in ("min_norm_level", "warm_start"))):
                raise InvalidSettings(solver, f"setting '{key}' must be true or false, got {value!r}", key)


def split_settings(solver: str, settings: Mapping[str, Any] | None) -> tuple[HqpSettings, dict[str, Any]]:
    """Split one config table into cascade options (:class:`HqpSettings`) and backend arguments.

    Raises:
        InvalidSettings: A cascade option has a bad value.
    """
    own = {f.name for f in fields(HqpSettings)}
    data = dict(settings or {})
    options = HqpSettings(**{k: data.pop(k) for k in list(data) if k in own})
    options.check(solver)
    return options, data


@dataclass(frozen=True)
class CascadeSettings:
    """:class:`HqpSettings` with every None resolved from the backend's record.

    Attributes:
        options: The options as given.
        tolerance: Accepted constraint violation of a backend answer [rad/s or m/s].
        slack_tolerance: A slack above this makes the step DEGRADED [task unit / s].
        slack_margin: Margin δ = 0.1 · ``tolerance`` added to a relaxed row, and to every row of the
            min-norm level, so that the feasible set keeps an interior.
        min_norm_level: Whether the final min-norm level is solved.
        objective_tolerance: Accepted error of a level's residual norm, relative to 1 + ρ.
        certificate_tolerances: The certificate's thresholds (primal: ``tolerance``, level:
            ``objective_tolerance``, active: ``max(1e-6, tolerance)``).
        warm_start: Whether each level starts from its previous-step answer.
    """

    options: HqpSettings
    tolerance: float
    slack_tolerance: float
    slack_margin: float
    min_norm_level: bool
    objective_tolerance: float
    certificate_tolerances: Tolerances
    warm_start: bool

    @classmethod
    def resolve(cls, options: HqpSettings, backend: QpBackend) -> CascadeSettings:
        """The options, each None replaced by the backend's default (or derived from the tolerance)."""
        tolerance = float(options.tolerance or backend.tolerance)
        objective_tolerance = float(options.objective_tolerance or max(1e-6, tolerance))
        return cls(
            options,
            tolerance,
            float(options.slack_tolerance or max(1e-6, tolerance)),
            0.1 * tolerance,
            backend.min_norm_level if options.min_norm_level is None else options.min_norm_level,
            objective_tolerance,
            Tolerances(primal=tolerance, level=objective_tolerance, active=max(1e-6, tolerance)),
            backend.warm_start if options.warm_start is None else options.warm_start,
        )

"""The shared task interface (docs/design.md §2): equality tasks, set-based tasks, their value objects."""

from __future__ import annotations

import abc
import enum
import math
import re
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from robots import Kinematics
from tpik.exceptions import InvalidTaskState, TaskDefinitionError, ThresholdOrderError
from tpik.reference import rate_bounds


@dataclass(frozen=True, slots=True, init=False)
class TaskState:
    r"""A task evaluated at one configuration.

    The closed-loop inverse kinematics reference of the task (paper eq. 2) is
    :math:`\dot\sigma_d + K\tilde\sigma` with :math:`\tilde\sigma = \sigma_d - \sigma`.

    Args:
        value: Task value σ. Shape (m,).
        jacobian: Task Jacobian J = ∂σ/∂q. Shape (m, n).
        desired: Desired value σ_d. Shape (m,).
        feedforward: Desired task velocity σ̇_d. Shape (m,).
        error: Task error σ̃; ``None`` = ``desired - value``. Tasks on SO(3) pass their own
            (log-map) error. Shape (m,).
    """

    value: np.ndarray
    jacobian: np.ndarray
    desired: np.ndarray
    feedforward: np.ndarray
    error: np.ndarray

    def __init__(
        self,
        value: np.ndarray,
        jacobian: np.ndarray,
        desired: np.ndarray,
        feedforward: np.ndarray,
        error: np.ndarray | None = None,
    ) -> None:
        object.__setattr__(self, "value", value)
        object.__setattr__(self, "jacobian", jacobian)
        object.__setattr__(self, "desired", desired)
        object.__setattr__(self, "feedforward", feedforward)
        object.__setattr__(self, "error", desired - value if error is None else error)

    @property
    def dim(self) -> int:
        """Task dimension ``m``."""
        return int(self.value.shape[0])

    def validate(self, name: str, nq: int) -> None:
        """Raise :class:`InvalidTaskState` if shapes disagree or the Jacobian is not finite."""
        m = self.value.shape[0]
        for label, arr, shape in (
            ("jacobian", self.jacobian, (m, nq)),
            ("desired", self.desired, (m,)),
            ("feedforward", self.feedforward, (m,)),
            ("error", self.error, (m,)),
        ):
            if arr.shape != shape:
                raise InvalidTaskState(f"task '{name}': {label} has shape {arr.shape}, expected {shape}")
        if not np.all(np.isfinite(self.jacobian)):
            raise InvalidTaskState(f"task '{name}': jacobian has non-finite entries")


class Task(abc.ABC):
    """A control objective σ(q) ∈ R^m with its Jacobian.

    Attributes:
        name: Unique name in a hierarchy.
        dim: Task dimension ``m``.
        gain: Closed-loop gain K (scalar, K = gain·I) [1/s].
    """

    def __init__(self, name: str, dim: int, gain: float) -> None:
        if not name:
            raise TaskDefinitionError("task name must be a non-empty string")
        if dim < 1:
            raise TaskDefinitionError(f"task '{name}': dim must be >= 1, got {dim}")
        if not (math.isfinite(gain) and gain > 0.0):
            raise TaskDefinitionError(f"task '{name}': gain must be a finite number > 0, got {gain}")
        self.name = name
        self.dim = int(dim)
        self.gain = float(gain)

    @abc.abstractmethod
    def compute_state(self, kin: Kinematics) -> TaskState:
        """Evaluate value, Jacobian, desired value and feedforward at ``kin.q``."""

    @property
    def is_set_based(self) -> bool:
        """Whether the task constrains σ to an interval rather than to a value."""
        return False

    def __repr__(self) -> str:
        return f"{type(self).__name__}(name={self.name!r}, dim={self.dim}, gain={self.gain:g})"


class Activation(enum.Enum):
    """Which side of a set-based task's valid set σ has reached (paper eq. 7)."""

    INACTIVE = 0
    LOWER = -1
    UPPER = 1


@dataclass(frozen=True, slots=True)
class Thresholds:
    r"""Thresholds of a scalar set-based task (paper sec. II, Fig. 1).

    .. math::
        \sigma_m < \sigma_{s,l} < \sigma_{a,l} \le \sigma_{a,u} < \sigma_{s,u} < \sigma_M,\quad
        \sigma_{a,l} = \sigma_{s,l} + \varepsilon,\quad \sigma_{a,u} = \sigma_{s,u} - \varepsilon

    A one-sided task sets both thresholds of the free side to ±inf.

    Attributes:
        physical_lower: σ_m, where the real constraint is broken.
        safety_lower: σ_{s,l}, the value held when the task is active from below.
        safety_upper: σ_{s,u}.
        physical_upper: σ_M.
        activation_margin: ε > 0, distance inside the safety thresholds at which the task
            activates. Same unit as σ.
    """

    physical_lower: float
    safety_lower: float
    safety_upper: float
    physical_upper: float
    activation_margin: float

    def check(self, task: str) -> None:
        """Raise :class:`ThresholdOrderError` naming the first two values out of order."""
        eps = self.activation_margin
        if not (math.isfinite(eps) and eps > 0.0):
            raise TaskDefinitionError(f"task '{task}': activation_margin must be finite and > 0, got {eps}")
        values = [self.physical_lower, self.safety_lower, self.safety_upper, self.physical_upper]
        if any(math.isnan(v) for v in values):
            raise TaskDefinitionError(f"task '{task}': thresholds must not be NaN: {values}")
        pairs = (
            ("physical_lower", self.physical_lower, "safety_lower", self.safety_lower),
            ("safety_upper", self.safety_upper, "physical_upper", self.physical_upper),
        )
        for lo_name, lo, hi_name, hi in pairs:
            both_infinite = math.isinf(lo) and math.isinf(hi) and (lo < 0) == (hi < 0)
            if not both_infinite and not lo < hi:
                raise ThresholdOrderError(task, lo_name, lo, hi_name, hi)
        if math.isinf(self.safety_lower) and math.isinf(self.safety_upper):
            raise TaskDefinitionError(f"task '{task}': at least one safety threshold must be finite")
        if not self.activation_lower <= self.activation_upper:
            raise ThresholdOrderError(
                task,
                "safety_lower + activation_margin",
                self.activation_lower,
                "safety_upper - activation_margin",
                self.activation_upper,
            )

    @property
    def activation_lower(self) -> float:
        """σ_{a,l} = σ_{s,l} + ε."""
        return self.safety_lower + self.activation_margin

    @property
    def activation_upper(self) -> float:
        """σ_{a,u} = σ_{s,u} − ε."""
        return self.safety_upper - self.activation_margin


_GROUP_NAME = re.compile(r"[a-z][a-z0-9_]*")


class SetTask(Task):
    """A scalar set-based task: keep σ within [σ_{s,l}, σ_{s,u}] (paper eqs. 7–9).

    Subclasses implement :meth:`compute_value_and_jacobian`; the desired value and the
    activation logic come from the thresholds. When σ cannot be evaluated (e.g. no obstacle
    in range) the value is ``+inf`` or ``-inf`` *outside* any activation zone's reach and the
    Jacobian is zero: every solver treats the task as inactive.

    Every set task belongs to a metrics ``group`` (``joint_limits``, ``walls``, ``obstacles``, or
    a new one): ``summary.json`` reports the worst margins and the violations of each group under
    its name (``compare.analysis.metrics``). A subclass names its group in :attr:`default_group`.

    Args:
        name: Task name.
        thresholds: Thresholds, in σ's unit.
        gain: K [1/s].
        group: Metrics group; ``None`` = :attr:`default_group`. Lower-case letters, digits, ``_``.

    Attributes:
        thresholds: Validated :class:`Thresholds`.
        group: The task's metrics group.
    """

    default_group: ClassVar[str] = "other"
    """Group of the subclass's tasks unless one is given."""

    def __init__(self, name: str, thresholds: Thresholds, gain: float, group: str | None = None) -> None:
        super().__init__(name, 1, gain)
        thresholds.check(name)
        self.thresholds = thresholds
        self.group = self.default_group if group is None else group
        if not isinstance(self.group, str) or not _GROUP_NAME.fullmatch(self.group):
            raise TaskDefinitionError(
                f"task '{name}': group must be lower-case letters, digits and '_' (a JSON key), got {self.group!r}"
            )

    @property
    def is_set_based(self) -> bool:
        """Always true."""
        return True

    @abc.abstractmethod
    def compute_value_and_jacobian(self, kin: Kinematics) -> tuple[float, np.ndarray]:
        """Return σ and the Jacobian row of shape (1, n)."""

    def compute_value(self, kin: Kinematics) -> float:
        """σ alone.

        Solvers call this for every set task and the Jacobian only for the few near a
        threshold; subclasses override it when σ is cheaper than σ and J together.
        """
        return self.compute_value_and_jacobian(kin)[0]

    def compute_jacobian(self, kin: Kinematics) -> np.ndarray:
        """The Jacobian row alone, shape (1, n) (see :meth:`compute_value`)."""
        return self.compute_value_and_jacobian(kin)[1]

    def compute_state(self, kin: Kinematics) -> TaskState:
        """Evaluate σ and J; σ_d is the safety threshold σ is closest to (eq. 7), else σ."""
        sigma, jac = self.compute_value_and_jacobian(kin)
        th = self.thresholds
        lower, upper = self.activation_bounds()
        if sigma >= upper:
            desired = th.safety_upper
        elif sigma <= lower:
            desired = th.safety_lower
        else:
            desired = sigma
        if not math.isfinite(desired):
            desired = sigma
        value = np.array([sigma])
        error = np.array([desired - sigma]) if math.isfinite(sigma) else np.zeros(1)
        return TaskState(value, jac, np.array([desired]), np.zeros(1), error)

    def activation_bounds(self) -> tuple[float, float]:
        r"""The activation thresholds (σ_{a,l}, σ_{a,u}) of this step, moved by the rate feed-forward f.

        A task is past its activation threshold where its reference rate
        :math:`K(\sigma_s - \sigma) + f` asks at least what it asks at σ_a without f (eq. 7):
        :math:`\sigma_{a,l} + \max(f, 0)/K` and :math:`\sigma_{a,u} + \min(f, 0)/K`. With f = 0
        (no prediction) these are the thresholds; f only ever brings the activation earlier.
        """
        th, f = self.thresholds, self.rate_feedforward
        if f == 0.0 or self.gain <= 0.0:
            return th.activation_lower, th.activation_upper
        return th.activation_lower + max(f, 0.0) / self.gain, th.activation_upper + min(f, 0.0) / self.gain

    def activation_state(self, state: TaskState) -> Activation:
        """Which activation threshold (:meth:`activation_bounds`) σ has crossed (eq. 7); INACTIVE for a non-finite σ."""
        sigma = float(state.value[0])
        if not math.isfinite(sigma):
            return Activation.INACTIVE
        lower, upper = self.activation_bounds()
        if sigma >= upper:
            return Activation.UPPER
        if sigma <= lower:
            return Activation.LOWER
        return Activation.INACTIVE

    def velocity_bounds(self, state: TaskState, dt: float, gain_cap: bool = True) -> tuple[float, float]:
        r"""Bounds on σ̇ that keep σ inside the safety set one step ahead (used by HQP and mink).

        .. math::
            K(\sigma_{s,l} - \sigma) + f \le \dot\sigma \le K(\sigma_{s,u} - \sigma) + f,
            \quad K = \min(\text{gain}, 1/dt)

        The one control reference of :mod:`tpik.reference`: capping K at 1/dt (``gain_cap``)
        makes the explicit Euler step land at most on the threshold; f is
        :attr:`rate_feedforward`. A non-finite σ gives
        (−inf, +inf).
        """
        th = self.thresholds
        return rate_bounds(
            float(state.value[0]), th.safety_lower, th.safety_upper, self.gain, dt, gain_cap, self.rate_feedforward
        )

    @property
    def rate_feedforward(self) -> float:
        r"""f: the rate of σ the arm must add to cancel what moves σ besides the arm [σ unit/s].

        Added to both reference rates (:func:`tpik.reference.rate_bounds`). 0 here: only the arm
        moves σ. :class:`~tpik.tasks.ObstacleDistanceTask` gives the predicted approach of the
        obstacle.
        """
        return 0.0

    def margins(self, sigma: float) -> tuple[float, float]:
        """Signed margins (safety, physical) of σ: > 0 inside the set, < 0 violated."""
        th = self.thresholds
        safety = min(sigma - th.safety_lower, th.safety_upper - sigma)
        physical = min(sigma - th.physical_lower, th.physical_upper - sigma)
        return safety, physical

    def __repr__(self) -> str:
        th = self.thresholds
        return (
            f"{type(self).__name__}(name={self.name!r}, safety=[{th.safety_lower:g}, "
            f"{th.safety_upper:g}], eps={th.activation_margin:g}, gain={self.gain:g})"
        )

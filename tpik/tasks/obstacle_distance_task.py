"""Obstacle distance of a control point (set-based, m = 1; paper sec. III)."""

from __future__ import annotations

import math

import numpy as np

from robots import Kinematics, Robot
from tpik.exceptions import InvalidTaskState
from tpik.tasks._targets import as_finite_vector
from tpik.tasks.registry import GAIN_KEY, GROUP_KEY, TaskKey, TaskSpec
from tpik.tasks.task import SetTask, Task, Thresholds


class ObstacleDistanceTask(SetTask):
    r"""Keep a control point P away from its closest obstacle point O.

    .. math::
        \sigma = \|O - P\| - g,\qquad
        J = -\frac{(O - P)^T}{\|O - P\|}\, J^{1..j}_{pos}

    where :math:`J^{1..j}_{pos}` is the partial position Jacobian of the control point
    (columns ``j..n`` zero, paper sec. III). O is supplied from outside (depth sensing or
    geometry) with :meth:`set_obstacle`; O is taken as fixed over the step. With no obstacle
    (``None``) σ = +inf and J = 0: the task stays inactive.

    A prediction of the obstacle's motion enters through two numbers given with O (both 0
    without prediction, the paper's task): the margin growth g ≥ 0 [m] (σ ≥ σ_s holds exactly
    when ‖O − P‖ ≥ σ_s + g: every threshold grows by g) and the rate feed-forward f
    (:attr:`rate_feedforward`, the predicted closing speed [m/s], added to the reference rate).

    Args:
        name: Task name.
        frame: Control point frame (e.g. ``"link_4"``: the origin of joint 4).
        thresholds: Thresholds [m]; typically physical_lower > 0, safety_lower = 0.35, upper = inf.
        gain: K [1/s].
        joint: 1-based joint ``j`` of the control point; defaults to the joint moving ``frame``.
        group: Metrics group (default ``obstacles``).
    """

    default_group = "obstacles"

    def __init__(
        self,
        name: str,
        frame: str,
        thresholds: Thresholds,
        gain: float = 1.0,
        joint: int | None = None,
        group: str | None = None,
    ) -> None:
        super().__init__(name, thresholds, gain, group)
        self.frame = frame
        self.joint = joint
        self._obstacle: np.ndarray | None = None
        self._feedforward = 0.0
        self._growth = 0.0

    def set_obstacle(self, point: np.ndarray | None, rate_feedforward: float = 0.0, margin_growth: float = 0.0) -> None:
        """Set the closest obstacle point O [m] in the base frame (copied), or None.

        Args:
            point: O [m], or None (no obstacle: f and g are reset to 0).
            rate_feedforward: f [m/s], finite.
            margin_growth: g [m], finite and ≥ 0.
        """
        if point is None:
            self._obstacle, self._feedforward, self._growth = None, 0.0, 0.0
            return
        f, g = float(rate_feedforward), float(margin_growth)
        if not (math.isfinite(f) and math.isfinite(g) and g >= 0.0):
            raise InvalidTaskState(
                f"task '{self.name}': rate_feedforward must be finite and margin_growth finite and >= 0, got {f}, {g}"
            )
        self._obstacle = as_finite_vector(self.name, "obstacle", point, 3)
        self._obstacle.flags.writeable = False
        self._feedforward, self._growth = f, g

    @property
    def rate_feedforward(self) -> float:
        """f: the predicted closing speed of the obstacle, added to the reference rate [m/s]."""
        return self._feedforward

    @property
    def margin_growth(self) -> float:
        """g: how far every threshold is moved out by the prediction [m]."""
        return self._growth

    @property
    def obstacle(self) -> np.ndarray | None:
        """A copy of O [m], or None."""
        return None if self._obstacle is None else self._obstacle.copy()

    @property
    def obstacle_point(self) -> np.ndarray | None:
        """O [m] itself, not a copy (read-only), or None; a new array at every :meth:`set_obstacle`."""
        return self._obstacle

    def compute_value(self, kin: Kinematics) -> float:
        """σ = ‖O − P‖ − g [m]; +inf without obstacle."""
        if self._obstacle is None:
            return math.inf
        diff = self._obstacle - kin.frame_position(self.frame)
        dist = math.sqrt(diff.dot(diff))
        return (0.0 if dist < 1e-9 else dist) - self._growth  # as compute_value_and_jacobian

    def compute_value_and_jacobian(self, kin: Kinematics) -> tuple[float, np.ndarray]:
        """σ = ‖O − P‖ − g and the paper's partial-Jacobian row; (inf, 0) without obstacle."""
        if self._obstacle is None:
            return math.inf, np.zeros((1, kin.nq))
        diff = self._obstacle - kin.frame_position(self.frame)
        dist = math.sqrt(diff.dot(diff))
        if dist < 1e-9:
            # O on P: the direction is undefined; report contact with no usable gradient.
            return -self._growth, np.zeros((1, kin.nq))
        diff *= -1.0 / dist
        return dist - self._growth, diff.dot(kin.partial_position_jacobian(self.frame, self.joint))[None, :]


OBSTACLE_DISTANCE_KEYS: tuple[TaskKey, ...] = (
    TaskKey("frame", "control point frame (or give `frames`; neither: the robot's default control points)", None),
    TaskKey("frames", "control point frames, one task each (or give `frame`)", None),
    TaskKey("safety_distance", "σ_{s,l}: distance held from the closest obstacle point", 0.35, "m"),
    TaskKey("physical_distance", "σ_m: distance below which the arm touches (< safety_distance)", 0.1, "m"),
    TaskKey("activation_margin", "ε: activation threshold beyond the safety distance", 0.05, "m"),
    GAIN_KEY,
    TaskKey("name", "task name, only with a single `frame` (default `obstacle_<frame>`)", None),
    GROUP_KEY,
)
"""Keys of an ``obstacle_distance`` description."""


def build_obstacle_distances(spec: TaskSpec, robot: Robot) -> list[Task]:
    """``obstacle_distance``: one :class:`ObstacleDistanceTask` per control point."""
    if spec.given("frame") or spec.given("frames"):
        frames = spec.frames(spec.one_or_many("frame", "frames"))
    else:  # the robot's default control points
        frames = list(robot.control_points)
    safety = spec.number("safety_distance", positive=True)
    physical = spec.number("physical_distance")
    eps = spec.number("activation_margin", positive=True)
    gain = spec.number("gain", positive=True)
    name = spec.name_for(len(frames), "frame")
    group = spec.optional_text("group")
    if not physical < safety:
        raise spec.error("safety_distance", f"must be > physical_distance={physical:g} m, got {safety:g}")
    th = Thresholds(physical, safety, math.inf, math.inf, eps)
    tasks: list[Task] = []
    for frame in frames:
        with spec.about("physical_distance", "safety_distance", "activation_margin"):
            tasks.append(ObstacleDistanceTask(name or f"obstacle_{frame}", frame, th, gain, group=group))
    return tasks

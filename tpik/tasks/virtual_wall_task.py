"""Virtual wall: signed distance of a frame origin to a plane (set-based, m = 1)."""

from __future__ import annotations

import math

import numpy as np

from robots import Kinematics, Robot
from tpik.exceptions import TaskDefinitionError
from tpik.tasks._targets import as_finite_vector
from tpik.tasks.registry import FRAME_KEY, GAIN_KEY, GROUP_KEY, TaskKey, TaskSpec
from tpik.tasks.task import SetTask, Task, Thresholds


class VirtualWallTask(SetTask):
    r"""Keep a frame origin on the allowed side of a plane ``n·p = offset``.

    .. math:: \sigma = n^T p(q) - d,\quad J = n^T J_{pos}(q),\quad \|n\| = 1

    σ > 0 on the side ``n`` points to. With ``safety_lower = 0`` the safety threshold is
    the wall itself.

    Args:
        name: Task name.
        frame: Robot frame (e.g. ``"end_effector"``).
        normal: Plane normal in the base frame (normalised here), pointing into the allowed side.
        offset: d [m]: the plane is ``n·p = d``.
        thresholds: Thresholds [m] on the signed distance.
        gain: K [1/s].
        group: Metrics group (default ``walls``).
    """

    default_group = "walls"

    def __init__(
        self,
        name: str,
        frame: str,
        normal: np.ndarray,
        offset: float,
        thresholds: Thresholds,
        gain: float = 1.0,
        group: str | None = None,
    ) -> None:
        super().__init__(name, thresholds, gain, group)
        n = as_finite_vector(name, "normal", normal, 3)
        norm = float(np.linalg.norm(n))
        if norm < 1e-9:
            raise TaskDefinitionError(f"task '{name}': normal must be non-zero")
        self.frame = frame
        self.normal = n / norm
        self.offset = float(as_finite_vector(name, "offset", offset, 1)[0]) / norm

    def compute_value(self, kin: Kinematics) -> float:
        """σ = nᵀp − d [m]."""
        return float(self.normal.dot(kin.frame_position(self.frame))) - self.offset

    def compute_jacobian(self, kin: Kinematics) -> np.ndarray:
        """J = nᵀ J_pos, shape (1, n)."""
        return self.normal.dot(kin.position_jacobian(self.frame))[None, :]

    def compute_value_and_jacobian(self, kin: Kinematics) -> tuple[float, np.ndarray]:
        """σ = nᵀp − d, J = nᵀ J_pos."""
        return self.compute_value(kin), self.compute_jacobian(kin)


def wall_thresholds(physical_margin: float, activation_margin: float) -> Thresholds:
    """One-sided wall thresholds [m]: the wall (σ = 0) is the safety threshold, σ_m = −physical_margin."""
    return Thresholds(-physical_margin, 0.0, math.inf, math.inf, activation_margin)


_PHYSICAL_MARGIN = TaskKey("physical_margin", "physical threshold this far past the wall (σ_m = −margin)", 0.05, "m")
_WALL_ACTIVATION = TaskKey("activation_margin", "ε: activation threshold this far inside the wall", 0.03, "m")

VIRTUAL_WALL_KEYS: tuple[TaskKey, ...] = (
    TaskKey("name", "task name"),
    FRAME_KEY,
    TaskKey("normal", "plane normal in the base frame, pointing into the allowed side (normalised)"),
    TaskKey("offset", "d of the plane n·p = d (before normalising n)", unit="m"),
    _PHYSICAL_MARGIN,
    _WALL_ACTIVATION,
    GAIN_KEY,
    GROUP_KEY,
)
"""Keys of a ``virtual_wall`` description."""


def build_virtual_wall(spec: TaskSpec, robot: Robot) -> list[Task]:
    """``virtual_wall``: one plane, the frame kept on the side the normal points to."""
    name = spec.text("name")
    frame = spec.frame("frame")
    normal = spec.array("normal", (3,))
    offset = spec.number("offset")
    th = wall_thresholds(spec.number("physical_margin", positive=True), spec.number("activation_margin", positive=True))
    if float(np.linalg.norm(normal)) < 1e-9:
        raise spec.error("normal", "must be non-zero")
    gain = spec.number("gain", positive=True)
    with spec.about("physical_margin", "activation_margin"):
        return [VirtualWallTask(name, frame, normal, offset, th, gain, spec.optional_text("group"))]


WALL_BOX_KEYS: tuple[TaskKey, ...] = (
    FRAME_KEY,
    TaskKey("lower", "lower corner (x, y, z) of the allowed box, base frame", unit="m"),
    TaskKey("upper", "upper corner (x, y, z) of the allowed box, base frame", unit="m"),
    _PHYSICAL_MARGIN,
    _WALL_ACTIVATION,
    GAIN_KEY,
    GROUP_KEY,
)
"""Keys of a ``wall_box`` description."""

_AXES = {"x": np.array([1.0, 0.0, 0.0]), "y": np.array([0.0, 1.0, 0.0]), "z": np.array([0.0, 0.0, 1.0])}


def build_wall_box(spec: TaskSpec, robot: Robot) -> list[Task]:
    """``wall_box``: six walls ``wall_<axis>_min`` / ``wall_<axis>_max`` of an axis-aligned box."""
    frame = spec.frame("frame")
    lower = spec.array("lower", (3,))
    upper = spec.array("upper", (3,))
    th = wall_thresholds(spec.number("physical_margin", positive=True), spec.number("activation_margin", positive=True))
    gain = spec.number("gain", positive=True)
    group = spec.optional_text("group")
    walls: list[Task] = []
    for axis_index, axis in enumerate("xyz"):
        lo, hi = float(lower[axis_index]), float(upper[axis_index])
        if not lo < hi:
            raise spec.error("lower", f"lower {axis}={lo:g} must be < upper {axis}={hi:g}")
        n = _AXES[axis]
        # σ = n·p − d ≥ 0 inside; the wall itself is the safety threshold.
        walls.append(VirtualWallTask(f"wall_{axis}_min", frame, n, lo, th, gain, group))
        walls.append(VirtualWallTask(f"wall_{axis}_max", frame, -n, -hi, th, gain, group))
    return walls

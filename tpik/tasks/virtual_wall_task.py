"""Virtual wall: signed distance of a frame origin to a plane (set-based, m = 1)."""

from __future__ import annotations

import numpy as np

from robots import Kinematics
from tpik.exceptions import TaskDefinitionError
from tpik.tasks._targets import as_finite_vector
from tpik.tasks.task import SetTask, Thresholds


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
    """

    def __init__(
        self,
        name: str,
        frame: str,
        normal: np.ndarray,
        offset: float,
        thresholds: Thresholds,
        gain: float = 1.0,
    ) -> None:
        super().__init__(name, thresholds, gain)
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

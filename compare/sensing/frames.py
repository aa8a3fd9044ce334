"""What a depth camera is and what it delivers: the pinhole model and one depth image."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class CameraModel:
    """Pinhole depth camera: intrinsics and pose in the arm base frame.

    Attributes:
        width: Image width [px].
        height: Image height [px].
        fx: Focal length along u [px].
        fy: Focal length along v [px].
        cx: Principal point u [px].
        cy: Principal point v [px].
        transform_base_to_camera: Pose of the optical frame (x right, y down, z forward) in
            the base frame, 4×4. A point p_cam maps to p_base = T[:3, :3] p_cam + T[:3, 3].
        min_range_m: Closest valid depth [m].
        max_range_m: Farthest valid depth [m].
    """

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    transform_base_to_camera: np.ndarray
    min_range_m: float = 0.5
    max_range_m: float = 4.5


@dataclass(frozen=True)
class DepthFrame:
    """One depth image along the optical axis.

    Attributes:
        depth_m: Depth [m], float32, shape (height, width); 0 or NaN = no return.
        stamp_s: Capture time on the backend's clock [s].
        camera: The camera that took it.
    """

    depth_m: np.ndarray
    stamp_s: float
    camera: CameraModel

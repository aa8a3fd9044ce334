"""Unit and message-field conversions at the ROS boundary (no ROS import here).

Everything inside the project is SI (rad, rad/s, m). The kinova-ros driver takes joint
velocities in **degrees per second** and publishes joint positions in rad; depth images come
as 16UC1 (mm) or 32FC1 (m). These functions are the only places where those units appear,
and their names say which unit goes in and out.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from compare.hardware.exceptions import HardwareError
from compare.sensing.frames import CameraModel

DEG_PER_RAD = 180.0 / math.pi

DEPTH_ENCODINGS = ("16UC1", "mono16", "32FC1")
"""Depth encodings understood: 16-bit unsigned millimetres (``mono16`` is the same layout), 32-bit float metres."""


def rad_s_to_deg_s(qdot_rad_s: np.ndarray) -> np.ndarray:
    """Joint velocities [rad/s] → [deg/s] for ``kinova_msgs/JointVelocity``."""
    return np.asarray(qdot_rad_s, dtype=float) * DEG_PER_RAD


def deg_s_to_rad_s(qdot_deg_s: np.ndarray) -> np.ndarray:
    """Joint velocities [deg/s] (driver command) → [rad/s]."""
    return np.asarray(qdot_deg_s, dtype=float) / DEG_PER_RAD


def joint_indices(names: Sequence[str], wanted: Sequence[str]) -> np.ndarray:
    """Index in ``names`` of every name of ``wanted``, in ``wanted``'s order.

    Raises:
        HardwareError: a wanted joint is missing (the message lists what the driver sent).
    """
    lookup = {name: i for i, name in enumerate(names)}
    missing = [w for w in wanted if w not in lookup]
    if missing:
        raise HardwareError(f"joint state lacks {missing}; it has {list(names)} (check hardware.joint_names)")
    return np.array([lookup[w] for w in wanted], dtype=int)


def decode_depth(encoding: str, height: int, width: int, step: int, is_bigendian: bool, data: bytes) -> np.ndarray:
    """A ``sensor_msgs/Image`` depth payload → depth [m], float32, shape (height, width).

    Invalid pixels (0 in 16UC1, NaN/±inf/≤0 in 32FC1) become 0 (no return), as in
    :class:`~compare.loop.robot_io.DepthFrame`. Row padding (``step`` > width × pixel size) is skipped.

    Raises:
        HardwareError: unknown encoding or a payload of the wrong size.
    """
    if encoding in ("16UC1", "mono16"):
        dtype, scale = np.dtype(">u2" if is_bigendian else "<u2"), 1e-3
    elif encoding == "32FC1":
        dtype, scale = np.dtype(">f4" if is_bigendian else "<f4"), 1.0
    else:
        raise HardwareError(f"depth encoding '{encoding}' not supported; expected one of {DEPTH_ENCODINGS}")
    row_bytes = width * dtype.itemsize
    if step < row_bytes or len(data) < step * height:
        raise HardwareError(f"depth image {width}x{height} {encoding}: step {step} and {len(data)} bytes are too small")
    raw = np.frombuffer(data, dtype=np.uint8, count=step * height).reshape(height, step)[:, :row_bytes]
    values = np.ascontiguousarray(raw).view(dtype).reshape(height, width)
    depth_m = values.astype(np.float32) * np.float32(scale)
    depth_m[~np.isfinite(depth_m) | (depth_m <= 0.0)] = 0.0
    return depth_m


def encode_depth(depth_m: np.ndarray, encoding: str = "16UC1") -> tuple[int, bytes]:
    """Depth [m] → (step, little-endian payload) of a ``sensor_msgs/Image`` (for the stand-in).

    16UC1 rounds to whole millimetres and saturates at 65.535 m; invalid pixels become 0.

    Raises:
        HardwareError: unknown encoding.
    """
    depth = np.asarray(depth_m, dtype=np.float64)
    valid = np.isfinite(depth) & (depth > 0.0)
    if encoding in ("16UC1", "mono16"):
        mm = np.where(valid, np.clip(np.rint(depth * 1e3), 0, 65535), 0).astype("<u2")
        return depth.shape[1] * 2, mm.tobytes()
    if encoding == "32FC1":
        m = np.where(valid, depth, 0.0).astype("<f4")
        return depth.shape[1] * 4, m.tobytes()
    raise HardwareError(f"depth encoding '{encoding}' not supported; expected one of {DEPTH_ENCODINGS}")


def transform_from_translation_quaternion(
    translation_m: Sequence[float], quaternion_xyzw: Sequence[float]
) -> np.ndarray:
    """Homogeneous transform from a translation [m] and a unit quaternion (x, y, z, w). Shape (4, 4)."""
    x, y, z, w = (float(v) for v in quaternion_xyzw)
    n = math.sqrt(x * x + y * y + z * z + w * w)
    if not math.isfinite(n) or n < 1e-9:
        raise HardwareError(f"quaternion {list(quaternion_xyzw)} has no orientation (norm {n:.3g})")
    x, y, z, w = x / n, y / n, z / n, w / n
    T = np.eye(4)
    T[:3, :3] = [
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ]
    T[:3, 3] = np.asarray(translation_m, dtype=float)
    return T


def translation_quaternion_from_transform(T: np.ndarray) -> tuple[tuple[float, float, float], tuple[float, ...]]:
    """Inverse of :func:`transform_from_translation_quaternion`: (translation [m], quaternion (x, y, z, w), w ≥ 0)."""
    R = np.asarray(T, dtype=float)[:3, :3]
    tr = float(np.trace(R))
    if tr > 0.0:
        s = 2.0 * math.sqrt(tr + 1.0)
        w, x, y, z = 0.25 * s, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s
    elif R[0, 0] > R[1, 1] and R[0, 0] > R[2, 2]:
        s = 2.0 * math.sqrt(1.0 + R[0, 0] - R[1, 1] - R[2, 2])
        w, x, y, z = (R[2, 1] - R[1, 2]) / s, 0.25 * s, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s
    elif R[1, 1] > R[2, 2]:
        s = 2.0 * math.sqrt(1.0 + R[1, 1] - R[0, 0] - R[2, 2])
        w, x, y, z = (R[0, 2] - R[2, 0]) / s, (R[0, 1] + R[1, 0]) / s, 0.25 * s, (R[1, 2] + R[2, 1]) / s
    else:
        s = 2.0 * math.sqrt(1.0 + R[2, 2] - R[0, 0] - R[1, 1])
        w, x, y, z = (R[1, 0] - R[0, 1]) / s, (R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, 0.25 * s
    q = np.array([x, y, z, w])
    q = q / np.linalg.norm(q)
    if q[3] < 0.0:
        q = -q
    t = np.asarray(T, dtype=float)[:3, 3]
    return (float(t[0]), float(t[1]), float(t[2])), tuple(float(v) for v in q)


def camera_model_from_info(
    width: int,
    height: int,
    K: Sequence[float],
    transform_base_to_camera: np.ndarray,
    min_range_m: float,
    max_range_m: float,
) -> CameraModel:
    """A :class:`CameraModel` from ``sensor_msgs/CameraInfo`` fields and the calibrated pose.

    Args:
        width: Image width [px].
        height: Image height [px].
        K: Row-major 3×3 intrinsic matrix (9 values) [px].
        transform_base_to_camera: Pose of the optical frame in the base frame. Shape (4, 4).
        min_range_m: Closest valid depth [m].
        max_range_m: Farthest valid depth [m].

    Raises:
        HardwareError: the intrinsics are missing or degenerate.
    """
    k = [float(v) for v in K]
    if len(k) != 9 or not all(math.isfinite(v) for v in k) or k[0] <= 0.0 or k[4] <= 0.0:
        raise HardwareError(f"camera_info K = {k} is not a valid pinhole matrix (fx, fy must be > 0)")
    if width <= 0 or height <= 0:
        raise HardwareError(f"camera_info has an empty image size {width}x{height}")
    return CameraModel(
        width=int(width),
        height=int(height),
        fx=k[0],
        fy=k[4],
        cx=k[2],
        cy=k[5],
        transform_base_to_camera=np.array(transform_base_to_camera, dtype=float),
        min_range_m=float(min_range_m),
        max_range_m=float(max_range_m),
    )

r"""Pinhole geometry of the depth camera: intrinsics and extrinsics from the MuJoCo model, projection.

Conventions (paper sec. III): a pixel :math:`(u, v)` is the column and row index of the image
(pixel centres at integer coordinates), the depth :math:`d` is the distance along the optical
axis, and the sensor ("optical") frame has x right, y down, z forward. With the intrinsics
:math:`f s_x = f_x`, :math:`f s_y = f_y`, :math:`c_x`, :math:`c_y`,

.. math::
    P_{s,x} = \frac{(u - c_x)\, d}{f_x},\qquad P_{s,y} = \frac{(v - c_y)\, d}{f_y},\qquad
    P_{s,z} = d

and a sensor-frame point maps to the base frame as :math:`P = R P_s + t` with
:math:`(R, t)` = ``CameraModel.transform_base_to_camera``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numpy as np

from compare.sensing._frame_kernels import count_in_range
from compare.sensing.exceptions import SensingError, UnknownSceneElement
from compare.sensing.frames import CameraModel, DepthFrame

DEFAULT_RANGE_M = (0.5, 4.5)
"""Kinect v2 valid depth range [m], used when the model has no ``depth_camera_range`` numeric."""

RANGE_NUMERIC = "depth_camera_range"
"""Name of the MJCF ``<numeric>`` holding the camera's valid range ``min max`` [m]."""

# MuJoCo camera frame (x right, y up, looking along -z) -> optical frame (x right, y down, z forward).
_MJ_TO_OPTICAL = np.diag([1.0, -1.0, -1.0])


@dataclass(frozen=True)
class DepthNoise:
    r"""Depth noise and dropout of the simulated sensor (also the filters' noise allowance).

    .. math:: \tilde d = d + n,\quad n \sim \mathcal N(0, \sigma(d)^2),\quad
        \sigma(d) = \begin{cases} \sigma_0\, d / (1\,\mathrm{m}) & \text{proportional} \\
        \sigma_0 & \text{otherwise} \end{cases}

    and each pixel is dropped (set to 0, no return) with probability ``dropout``.

    Attributes:
        std_m: :math:`\sigma_0` [m] (at 1 m when ``proportional``).
        proportional: Whether σ grows linearly with depth.
        dropout: Fraction of pixels without return, in [0, 1].
    """

    std_m: float = 0.0
    proportional: bool = False
    dropout: float = 0.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.std_m) and self.std_m >= 0.0):
            raise SensingError(f"noise std_m must be finite and >= 0, got {self.std_m}")
        if not 0.0 <= self.dropout <= 1.0:
            raise SensingError(f"dropout must be in [0, 1], got {self.dropout}")

    def std_at(self, depth_m: float | np.ndarray) -> float | np.ndarray:
        """σ(d) [m] at depth ``depth_m``."""
        return self.std_m * depth_m if self.proportional else self.std_m + 0.0 * depth_m

    @property
    def is_zero(self) -> bool:
        """No noise and no dropout."""
        return self.std_m == 0.0 and self.dropout == 0.0


def camera_id(model: mujoco.MjModel, name: str) -> int:
    """Index of camera ``name``, or :class:`UnknownSceneElement` listing the cameras."""
    cam = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, name)
    if cam < 0:
        raise UnknownSceneElement("camera", name, [model.camera(i).name for i in range(model.ncam)])
    return int(cam)


def camera_model_from_mujoco(
    model: mujoco.MjModel,
    camera: str = "depth_camera",
    data: mujoco.MjData | None = None,
    resolution: tuple[int, int] | None = None,
) -> CameraModel:
    r"""Intrinsics and pose of a MuJoCo camera as a :class:`CameraModel` (one source of truth: the MJCF).

    Intrinsics come from the camera's ``resolution``, ``sensorsize``, ``focal[pixel]`` and
    ``principal[pixel]`` attributes; MuJoCo's principal offset :math:`(p_x, p_y)` [px] moves the
    principal point to :math:`c_x = (W-1)/2 - p_x`, :math:`c_y = (H-1)/2 - p_y` (checked by
    rendering in ``tests/compare/sensing/test_camera.py``). A camera given by ``fovy`` only gets
    :math:`f_x = f_y = (H/2)/\tan(\mathrm{fovy}/2)` and the centred principal point. The valid
    range is the camera's ``depth_camera_range:<camera>`` numeric, else the model's
    ``depth_camera_range``, else 0.5–4.5 m.

    Args:
        model: The scene model.
        camera: Camera name.
        data: Data whose ``cam_xpos``/``cam_xmat`` give the pose (required for a camera on a moving
            body, after ``mj_kinematics``); without it the camera must be fixed to the world body.
        resolution: (width, height) [px] for a camera without a ``resolution`` attribute.

    Returns:
        The camera model; the pose is that of the optical frame (x right, y down, z forward) in
        the world frame, which in our scenes is the arm base frame.
    """
    cam = camera_id(model, camera)
    res = model.cam_resolution[cam]
    width, height = (int(res[0]), int(res[1])) if resolution is None else (int(resolution[0]), int(resolution[1]))
    if width <= 1 or height <= 1:
        raise SensingError(f"camera '{camera}' has no resolution; pass resolution=(width, height)")
    sensor = model.cam_sensorsize[cam]
    if sensor[0] > 0 and sensor[1] > 0:
        fl_x, fl_y, pp_x, pp_y = model.cam_intrinsic[cam]
        px_per_m_x, px_per_m_y = width / sensor[0], height / sensor[1]
        fx, fy = fl_x * px_per_m_x, fl_y * px_per_m_y
        cx = (width - 1) / 2.0 - pp_x * px_per_m_x
        cy = (height - 1) / 2.0 - pp_y * px_per_m_y
    else:
        fy = (height / 2.0) / math.tan(math.radians(model.cam_fovy[cam]) / 2.0)
        fx = fy
        cx, cy = (width - 1) / 2.0, (height - 1) / 2.0
    if data is not None:
        pos = np.array(data.cam_xpos[cam])
        rot = np.array(data.cam_xmat[cam]).reshape(3, 3)
    else:
        if model.cam_bodyid[cam] != 0 or model.cam_mode[cam] != mujoco.mjtCamLight.mjCAMLIGHT_FIXED:
            raise SensingError(f"camera '{camera}' is not fixed to the world: pass data to read its pose")
        pos = np.array(model.cam_pos[cam])
        flat = np.empty(9)
        mujoco.mju_quat2Mat(flat, model.cam_quat[cam])
        rot = flat.reshape(3, 3)
    transform = np.eye(4)
    transform[:3, :3] = rot @ _MJ_TO_OPTICAL
    transform[:3, 3] = pos
    min_range, max_range = _range(model, camera)
    return CameraModel(width, height, float(fx), float(fy), float(cx), float(cy), transform, min_range, max_range)


def _range(model: mujoco.MjModel, camera: str) -> tuple[float, float]:
    """The camera's own ``depth_camera_range:<camera>`` numeric, else the scene's ``depth_camera_range``."""
    name = f"{RANGE_NUMERIC}:{camera}"
    idx = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_NUMERIC, name)
    if idx < 0:
        name = RANGE_NUMERIC
        idx = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_NUMERIC, name)
    if idx < 0:
        return DEFAULT_RANGE_M
    adr, size = int(model.numeric_adr[idx]), int(model.numeric_size[idx])
    if size != 2:
        raise SensingError(f"numeric '{name}' must hold 2 values (min max), got {size}")
    lo, hi = (float(v) for v in model.numeric_data[adr : adr + 2])
    if not 0.0 < lo < hi:
        raise SensingError(f"numeric '{name}' must satisfy 0 < min < max, got {lo} {hi}")
    return lo, hi


def look_at_rotation(position: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Axes of a MuJoCo camera (x right, y up, looking along −z) at ``position`` aimed at ``target``.

    Image x is kept horizontal (perpendicular to the world z axis); straight up or down, x is
    the world x axis. Returns the 3×3 rotation whose columns are the camera axes in the world.
    """
    pos = np.asarray(position, dtype=float)
    forward = np.asarray(target, dtype=float) - pos
    norm = np.linalg.norm(forward)
    if norm < 1e-9:
        raise SensingError("camera position and target coincide")
    forward /= norm
    right = np.cross(forward, [0.0, 0.0, 1.0])
    if np.linalg.norm(right) < 1e-6:  # looking straight up or down: pick x as "right"
        right = np.array([1.0, 0.0, 0.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    return np.column_stack([right, up, -forward])


def set_camera_look_at(
    model: mujoco.MjModel, position: np.ndarray, target: np.ndarray, camera: str = "depth_camera"
) -> None:
    """Move a world-fixed camera to ``position`` looking at ``target`` (base frame [m]), image x horizontal.

    Changes ``model.cam_pos``/``cam_quat`` in place; run ``mj_kinematics`` on existing data and
    rebuild any :class:`CameraModel` afterwards.
    """
    cam = camera_id(model, camera)
    if model.cam_bodyid[cam] != 0:
        raise SensingError(f"camera '{camera}' moves with a body; only world cameras can be re-aimed")
    pos = np.asarray(position, dtype=float)
    rot = look_at_rotation(pos, target)  # MuJoCo camera axes in the world
    quat = np.empty(4)
    mujoco.mju_mat2Quat(quat, rot.ravel())
    model.cam_pos[cam] = pos
    model.cam_quat[cam] = quat


def normalized_coordinates(camera: CameraModel) -> tuple[np.ndarray, np.ndarray]:
    r"""Per-column :math:`(u - c_x)/f_x` and per-row :math:`(v - c_y)/f_y`, float64, shapes (W,), (H,)."""
    xn = (np.arange(camera.width) - camera.cx) / camera.fx
    yn = (np.arange(camera.height) - camera.cy) / camera.fy
    return xn, yn


def base_to_sensor(camera: CameraModel, points: np.ndarray) -> np.ndarray:
    """Base-frame points [m], shape (N, 3) or (3,), in the sensor frame."""
    T = camera.transform_base_to_camera
    return (np.asarray(points, dtype=float) - T[:3, 3]) @ T[:3, :3]


def sensor_to_base(camera: CameraModel, points: np.ndarray) -> np.ndarray:
    """Sensor-frame points [m], shape (N, 3) or (3,), in the base frame."""
    T = camera.transform_base_to_camera
    return np.asarray(points, dtype=float) @ T[:3, :3].T + T[:3, 3]


def project(camera: CameraModel, points_base: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Depth-space coordinates of base-frame points.

    Args:
        camera: The camera.
        points_base: Points [m] in the base frame. Shape (N, 3).

    Returns:
        ``uv`` [px], shape (N, 2) (continuous; pixel centres at integers), and the depth ``d``
        along the optical axis [m], shape (N,). Points behind the camera get ``d <= 0``.
    """
    p = base_to_sensor(camera, np.atleast_2d(points_base))
    d = p[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = camera.cx + camera.fx * p[:, 0] / d
        v = camera.cy + camera.fy * p[:, 1] / d
    return np.column_stack([u, v]), d


def deproject(camera: CameraModel, uv: np.ndarray, depth_m: np.ndarray) -> np.ndarray:
    """Base-frame points of pixels ``uv`` [px], shape (N, 2), at depths ``depth_m`` [m], shape (N,).

    The inverse of :func:`project` (paper sec. III, :math:`P_s` from :math:`P_d`). Shape (N, 3).
    """
    uv = np.atleast_2d(np.asarray(uv, dtype=float))
    d = np.asarray(depth_m, dtype=float).reshape(-1)
    p = np.column_stack([(uv[:, 0] - camera.cx) * d / camera.fx, (uv[:, 1] - camera.cy) * d / camera.fy, d])
    return sensor_to_base(camera, p)


def valid_mask(frame: DepthFrame) -> np.ndarray:
    """Pixels with a return inside the camera's range (0, NaN and out-of-range are invalid). Shape (H, W)."""
    d = frame.depth_m
    with np.errstate(invalid="ignore"):
        return (d >= frame.camera.min_range_m) & (d <= frame.camera.max_range_m)


def valid_fraction(frame: DepthFrame) -> float:
    """Fraction of pixels of ``frame`` with a valid return, in [0, 1]."""
    d, cam = frame.depth_m, frame.camera
    if d.dtype == np.float32 and d.ndim == 2:  # the frames of the cameras: one compiled pass
        return float(count_in_range(d, np.float32(cam.min_range_m), np.float32(cam.max_range_m))) / d.size
    return float(np.count_nonzero(valid_mask(frame))) / d.size


def point_cloud(frame: DepthFrame, in_base_frame: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """The frame's valid pixels as 3-D points.

    Args:
        frame: A depth frame (0/NaN/out-of-range pixels are skipped).
        in_base_frame: Base frame (default) or sensor frame.

    Returns:
        Points [m], shape (N, 3), float64, and their pixel indices ``(v, u)``, shape (N, 2).
    """
    cam = frame.camera
    vs, us = np.divmod(np.flatnonzero(valid_mask(frame)), cam.width)
    d = frame.depth_m[vs, us].astype(float)
    p = np.column_stack([(us - cam.cx) * d / cam.fx, (vs - cam.cy) * d / cam.fy, d])
    pts = sensor_to_base(cam, p) if in_base_frame else p
    return pts, np.column_stack([vs, us])

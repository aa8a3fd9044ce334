r"""Several depth cameras in the work cell: ``[[sensor.cameras]]`` → cameras in the MuJoCo model.

The MJCF of the work cell holds one camera (``depth_camera``, the paper's Kinect). A rig adds
cameras to the scene, or re-aims and re-configures the scene's own, before compiling it
(``mujoco.MjSpec``): the scene file is never edited, and every camera is then an ordinary
MuJoCo camera read by :func:`compare.sensing.camera.camera_model_from_mujoco`.

Per camera (:class:`CameraLike`, e.g. ``compare.config.CameraConfig``):

* pose: ``position_m`` with ``look_at_m`` (image x horizontal) or ``quaternion_xyzw`` of the
  optical frame (x right, y down, z forward) in the base frame;
* intrinsics: ``resolution`` (W, H), ``focal_px`` (fx, fy), ``principal_px`` (cx, cy), written
  as MuJoCo's ``focalpixel``/``principalpixel`` with 10 µm pixels
  (:math:`c_x = (W-1)/2 - p_x`, :math:`c_y = (H-1)/2 - p_y`);
* valid range: ``range_m``, stored as the numeric ``depth_camera_range:<name>``.

A new camera without intrinsics gets the Kinect v2 depth stream's (:data:`KINECT_V2`); the
scene's camera keeps the MJCF's values for anything not given.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

import mujoco
import numpy as np

import robots
from compare.sensing.camera import RANGE_NUMERIC, look_at_rotation
from compare.sensing.exceptions import SensingError

PIXEL_PITCH_M = 1e-5
"""Sensor pixel size used to write pixel intrinsics into the MJCF [m] (the Kinect v2's 10 µm)."""


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics and valid range of a depth stream.

    Attributes:
        resolution: (width, height) [px].
        focal_px: (fx, fy) [px].
        principal_px: (cx, cy) [px].
        range_m: (min, max) valid depth [m].
    """

    resolution: tuple[int, int]
    focal_px: tuple[float, float]
    principal_px: tuple[float, float]
    range_m: tuple[float, float]


KINECT_V2 = Intrinsics((512, 424), (365.5, 365.5), (255.0, 205.0), (0.5, 4.5))
"""The Kinect v2 depth stream (docs/design.md §4): the default of a camera added to the scene."""


class CameraLike(Protocol):
    """What a rig needs to know about one camera (``compare.config.CameraConfig`` fits)."""

    @property
    def name(self) -> str:
        """Camera name."""

    @property
    def position_m(self) -> tuple[float, float, float] | None:
        """Optical centre [m] or None (keep the scene's)."""

    @property
    def look_at_m(self) -> tuple[float, float, float] | None:
        """Point on the optical axis [m] or None."""

    @property
    def quaternion_xyzw(self) -> tuple[float, float, float, float] | None:
        """Optical-frame orientation (x, y, z, w) or None."""

    @property
    def resolution(self) -> tuple[int, int] | None:
        """(width, height) [px] or None."""

    @property
    def focal_px(self) -> tuple[float, float] | None:
        """(fx, fy) [px] or None."""

    @property
    def principal_px(self) -> tuple[float, float] | None:
        """(cx, cy) [px] or None."""

    @property
    def range_m(self) -> tuple[float, float] | None:
        """(min, max) [m] or None."""


def scene_camera_names(robot: str = robots.DEFAULT_ROBOT) -> list[str]:
    """Names of the cameras the work-cell MJCF of ``robot`` defines."""
    return [c.name for c in robots.load(robot).workcell_spec().cameras]


def camera_quaternion(
    position: Sequence[float], look_at: Sequence[float] | None, quaternion_xyzw: Sequence[float] | None
) -> np.ndarray:
    """MuJoCo camera-frame quaternion (w, x, y, z) of a pose given by a target or an optical-frame quaternion."""
    if look_at is not None:
        rot = look_at_rotation(np.asarray(position, dtype=float), np.asarray(look_at, dtype=float))
    elif quaternion_xyzw is not None:
        x, y, z, w = (float(v) for v in quaternion_xyzw)
        flat = np.empty(9)
        mujoco.mju_quat2Mat(flat, np.array([w, x, y, z]) / np.linalg.norm([w, x, y, z]))
        rot = flat.reshape(3, 3) @ np.diag([1.0, -1.0, -1.0])  # optical → MuJoCo camera axes
    else:
        raise SensingError("a camera pose needs look_at_m or quaternion_xyzw")
    quat = np.empty(4)
    mujoco.mju_mat2Quat(quat, rot.ravel())
    return quat


def add_cameras(spec: mujoco.MjSpec, cameras: Sequence[CameraLike]) -> None:
    """Add or re-configure the ``cameras`` in ``spec`` (in place; see the module docstring).

    Raises:
        SensingError: A new camera without a pose.
    """
    existing = {c.name: c for c in spec.cameras}
    width_max, height_max = spec.visual.global_.offwidth, spec.visual.global_.offheight
    for cam in cameras:
        mj = existing.get(cam.name)
        if mj is None:
            if cam.position_m is None:
                raise SensingError(
                    f"camera '{cam.name}' is not in the scene ({', '.join(existing) or 'none'}): give its position_m "
                    "and look_at_m or quaternion_xyzw"
                )
            mj = spec.worldbody.add_camera(name=cam.name)
            _set_intrinsics(mj, KINECT_V2.resolution, KINECT_V2.focal_px, KINECT_V2.principal_px)
            _set_range(spec, cam.name, KINECT_V2.range_m)
        if cam.position_m is not None:
            mj.pos = np.asarray(cam.position_m, dtype=float)
            mj.alt.type = mujoco.mjtOrientation.mjORIENTATION_QUAT  # drop the MJCF's xyaxes
            mj.quat = camera_quaternion(cam.position_m, cam.look_at_m, cam.quaternion_xyzw)
        if cam.resolution is not None or cam.focal_px is not None or cam.principal_px is not None:
            resolution = tuple(int(v) for v in (cam.resolution or mj.resolution))
            focal = cam.focal_px or _focal_px(mj)
            principal = cam.principal_px or _principal_px(mj)
            _set_intrinsics(mj, (resolution[0], resolution[1]), focal, principal)
        if cam.range_m is not None:
            _set_range(spec, cam.name, cam.range_m)
        width_max = max(width_max, int(mj.resolution[0]))
        height_max = max(height_max, int(mj.resolution[1]))
    spec.visual.global_.offwidth = width_max
    spec.visual.global_.offheight = height_max


def _focal_px(cam: mujoco.MjsCamera) -> tuple[float, float]:
    if cam.focal_pixel[0] > 0:
        return float(cam.focal_pixel[0]), float(cam.focal_pixel[1])
    if cam.sensor_size[0] > 0 and cam.focal_length[0] > 0:
        return (
            float(cam.focal_length[0] * cam.resolution[0] / cam.sensor_size[0]),
            float(cam.focal_length[1] * cam.resolution[1] / cam.sensor_size[1]),
        )
    f = (cam.resolution[1] / 2.0) / np.tan(np.radians(cam.fovy) / 2.0)
    return float(f), float(f)


def _principal_px(cam: mujoco.MjsCamera) -> tuple[float, float]:
    width, height = (int(v) for v in cam.resolution)
    px, py = (float(v) for v in cam.principal_pixel)
    return (width - 1) / 2.0 - px, (height - 1) / 2.0 - py


def _set_intrinsics(
    cam: mujoco.MjsCamera, resolution: tuple[int, int], focal_px: Sequence[float], principal_px: Sequence[float]
) -> None:
    width, height = resolution
    cam.resolution = [width, height]
    cam.sensor_size = [width * PIXEL_PITCH_M, height * PIXEL_PITCH_M]
    cam.focal_length = [0.0, 0.0]
    cam.principal_length = [0.0, 0.0]
    cam.focal_pixel = [float(focal_px[0]), float(focal_px[1])]
    cam.principal_pixel = [(width - 1) / 2.0 - float(principal_px[0]), (height - 1) / 2.0 - float(principal_px[1])]


def range_numeric(camera: str) -> str:
    """Name of the numeric holding ``camera``'s valid range (``depth_camera_range:<name>``)."""
    return f"{RANGE_NUMERIC}:{camera}"


def _set_range(spec: mujoco.MjSpec, camera: str, range_m: Sequence[float]) -> None:
    name = range_numeric(camera)
    for numeric in spec.numerics:
        if numeric.name == name:
            numeric.data = [float(range_m[0]), float(range_m[1])]
            return
    spec.add_numeric(name=name, data=[float(range_m[0]), float(range_m[1])])


def load_rig_workcell(robot: str = robots.DEFAULT_ROBOT, cameras: Sequence[CameraLike] = ()) -> mujoco.MjModel:
    """The work cell of ``robot`` with ``cameras`` added or re-configured (no cameras: the work cell as is)."""
    spec = robots.load(robot).workcell_spec()
    add_cameras(spec, cameras)
    return spec.compile()

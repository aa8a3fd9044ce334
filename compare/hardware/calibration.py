r"""Camera calibration check: the arm model rendered from the configured camera vs the live depth.

The self-filter removes the arm's pixels by testing measured points against the arm model
placed with the configured camera pose (``[hardware] camera_translation_m``,
``camera_quaternion_xyzw``). If that pose is off by more than the self-filter margin (3 cm),
pieces of the arm survive the filter and become phantom obstacles next to the control points.
A classic way to be ~5 cm off: taking the Kinect v2's RGB optical frame for the IR (depth)
optical frame; the bridge's own ``calib_pose.yaml`` puts them ~5.2 cm apart (iai_kinect2).

The check renders the arm alone (its visual geoms, noise-free) at the measured joint positions
into a camera with the live ``camera_info`` intrinsics and the configured pose, and compares it
with the live depth frame over the arm's pixels :math:`A` (rendered arm, eroded by one pixel so
that silhouette edges and mixed pixels do not count; pixels without a measured return skipped):

.. math:: r = P_{75}\,\big\{ \left| d_{\text{meas}}(u, v) - d_{\text{model}}(u, v) \right| : (u, v) \in A \big\}

three quarters of the arm's pixels lie within :math:`r` of the model. The 75th percentile, not
the median: a sideways error leaves about half of the silhouette on the arm (a 5 cm shift along
the image x axis, the RGB/IR mix-up, gives a median of 2 cm but a 75th percentile of 22 cm in
the work cell), while a quarter of the pixels may still disagree for other reasons (cables,
parts the model lacks). A correct pose leaves the sensor noise (a few mm); 5 cm in any direction
gives more than 3 cm (tested; 1 cm gives about 1 cm). ``tpik-compare hw-check`` reports it, and
``tpik-compare hw`` refuses to move when :math:`r` > ``calibration_max_residual_m`` (2 cm, below
the self-filter's 3 cm margin). Nobody may stand between the camera and the arm during the check.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numpy as np
from scipy import ndimage

from compare.hardware.exceptions import HardwareError
from compare.sensing.camera import DepthNoise
from compare.sensing.frames import CameraModel
from compare.sensing.renderer import ROBOT_VISUAL_GROUP, DepthCamera
from compare.sensing.scene import load_workcell, make_data, set_arm_configuration

_PIXEL_M = 1e-5
"""Sensor pixel size used to express pixel intrinsics as MuJoCo's metric ``sensorsize``/``intrinsic``."""
_OPTICAL_TO_MJ = np.diag([1.0, -1.0, -1.0])
"""Optical frame (x right, y down, z forward) → MuJoCo camera frame (x right, y up, looking along −z)."""
MIN_ARM_PIXELS = 200
"""Fewer valid arm pixels than this: the check cannot conclude (arm out of view or occluded)."""


@dataclass(frozen=True)
class AlignmentResidual:
    """How well the arm model, seen from the configured camera, lies on the measured depth.

    Attributes:
        residual_m: :math:`r` of the module docstring: 75th percentile of the absolute depth error [m].
        median_abs_error_m: Median absolute depth error [m].
        mean_error_m: Mean signed error, measured − model [m] (positive: the arm is measured farther).
        within_2cm_fraction: Arm pixels whose error is below 2 cm.
        arm_pixels: Pixels of the rendered arm (after erosion).
        valid_pixels: Those with a measured return (the ones compared).
    """

    residual_m: float
    median_abs_error_m: float
    mean_error_m: float
    within_2cm_fraction: float
    arm_pixels: int
    valid_pixels: int

    @property
    def conclusive(self) -> bool:
        """Whether enough arm pixels were compared."""
        return self.valid_pixels >= MIN_ARM_PIXELS

    def describe(self) -> str:
        """One line for the log / CLI."""
        return (
            f"alignment residual {100 * self.residual_m:.1f} cm (75th percentile of the depth error over "
            f"{self.valid_pixels} arm pixels; median {100 * self.median_abs_error_m:.1f} cm, "
            f"{100 * self.within_2cm_fraction:.0f} % within 2 cm, "
            f"mean measured − model {100 * self.mean_error_m:+.1f} cm)"
        )

    def as_dict(self) -> dict[str, float | int]:
        """For summary.json."""
        return {
            "residual_m": self.residual_m,
            "median_abs_error_m": self.median_abs_error_m,
            "mean_error_m": self.mean_error_m,
            "within_2cm_fraction": self.within_2cm_fraction,
            "arm_pixels": self.arm_pixels,
            "valid_pixels": self.valid_pixels,
        }


def alignment_residual(measured_m: np.ndarray, model_m: np.ndarray, erode_px: int = 1) -> AlignmentResidual:
    """Compare a measured depth image with the rendered arm (both [m], 0 = no return; same shape).

    Raises:
        HardwareError: the images differ in shape.
    """
    measured = np.nan_to_num(np.asarray(measured_m, dtype=np.float64), nan=0.0, posinf=0.0, neginf=0.0)
    model = np.asarray(model_m, dtype=np.float64)
    if measured.shape != model.shape:
        raise HardwareError(f"depth image {measured.shape} and rendered arm {model.shape} differ in size")
    arm = model > 0.0
    if erode_px > 0:
        arm = ndimage.binary_erosion(arm, iterations=erode_px)
    valid = arm & (measured > 0.0)
    err = measured[valid] - model[valid]
    if err.size == 0:
        return AlignmentResidual(math.inf, math.inf, math.nan, 0.0, int(arm.sum()), 0)
    return AlignmentResidual(
        residual_m=float(np.percentile(np.abs(err), 75)),
        median_abs_error_m=float(np.median(np.abs(err))),
        mean_error_m=float(err.mean()),
        within_2cm_fraction=float(np.mean(np.abs(err) < 0.02)),
        arm_pixels=int(arm.sum()),
        valid_pixels=int(err.size),
    )


def set_mujoco_camera(model: mujoco.MjModel, name: str, camera: CameraModel) -> None:
    """Give the world-fixed MuJoCo camera ``name`` the intrinsics and pose of ``camera`` (in place).

    Pixel intrinsics become MuJoCo's metric ones with a nominal pixel of 10 µm: ``sensorsize``
    = (W, H) px × 10 µm, ``intrinsic`` = (fx, fy, pp_x, pp_y) × 10 µm with the principal offset
    pp = ((W − 1)/2 − cx, (H − 1)/2 − cy) (the convention of
    :func:`compare.sensing.camera.camera_model_from_mujoco`, which reads them back).
    """
    cam = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, name)
    if cam < 0:
        raise HardwareError(f"no camera '{name}' in the model")
    w, h = camera.width, camera.height
    model.vis.global_.offwidth = max(int(model.vis.global_.offwidth), w)
    model.vis.global_.offheight = max(int(model.vis.global_.offheight), h)
    model.cam_resolution[cam] = (w, h)
    model.cam_sensorsize[cam] = (w * _PIXEL_M, h * _PIXEL_M)
    model.cam_intrinsic[cam] = (
        camera.fx * _PIXEL_M,
        camera.fy * _PIXEL_M,
        ((w - 1) / 2.0 - camera.cx) * _PIXEL_M,
        ((h - 1) / 2.0 - camera.cy) * _PIXEL_M,
    )
    T = np.asarray(camera.transform_base_to_camera, dtype=float)
    rot = T[:3, :3] @ _OPTICAL_TO_MJ
    quat = np.empty(4)
    mujoco.mju_mat2Quat(quat, rot.reshape(-1))
    model.cam_pos[cam] = T[:3, 3]
    model.cam_quat[cam] = quat
    model.cam_fovy[cam] = math.degrees(2.0 * math.atan((h / 2.0) / camera.fy))


class ArmRenderer:
    """Noise-free depth of the arm alone, seen by a given camera (intrinsics and pose).

    Uses a private copy of the work cell's model (the arm with its visual geoms) whose depth
    camera is moved to ``camera`` (:func:`set_mujoco_camera`); only the arm's geoms are drawn.

    Args:
        camera: The camera: ``camera_info`` intrinsics, configured pose.
    """

    def __init__(self, camera: CameraModel) -> None:
        self._model = load_workcell()
        set_mujoco_camera(self._model, "depth_camera", camera)
        self._data = make_data(self._model)
        self._renderer = DepthCamera(self._model, noise=DepthNoise(), geom_groups=(ROBOT_VISUAL_GROUP,))
        self.camera = self._renderer.camera

    def render(self, q: np.ndarray) -> np.ndarray:
        """Depth [m] of the arm at joint positions ``q`` [rad] (0 where the arm is not), shape (H, W)."""
        set_arm_configuration(self._model, self._data, np.asarray(q, dtype=float))
        mujoco.mj_kinematics(self._model, self._data)
        return self._renderer.render_depth(self._data, noisy=False)

    def close(self) -> None:
        """Release the GL context."""
        self._renderer.close()


def check_alignment(camera: CameraModel, q: np.ndarray, measured_m: np.ndarray) -> AlignmentResidual:
    """Render the arm at ``q`` [rad] from ``camera`` and compare with ``measured_m`` [m]."""
    renderer = ArmRenderer(camera)
    try:
        return alignment_residual(measured_m, renderer.render(q))
    finally:
        renderer.close()

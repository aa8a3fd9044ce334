r"""Remove the arm and the static environment from depth frames before distance computation.

**Self-filter** (paper sec. III: the arm must be removed, otherwise every control point's
closest obstacle is the arm itself; the paper used the real-time URDF filter with inflated
boxes). Here each measured pixel is turned into its 3-D point and tested against the arm's
visual geoms (capsules, cylinder, boxes) inflated by a margin:

.. math:: \text{remove } (u, v) \iff \min_g \mathrm{sd}_g(P(u, v)) \le m + k\,\sigma(d)

with :math:`\mathrm{sd}_g` the signed distance to geom :math:`g` (negative inside), :math:`m`
the margin, :math:`\sigma(d)` the sensor noise at the pixel's depth and :math:`k` a noise
allowance (5σ by default: noise alone almost never lifts an arm pixel out of the filter).
Only pixels whose measured point lies on or near the arm are removed, not the arm's whole
silhouette: a hand touching the arm, or anything in front of it, survives. Each geom is
tested only inside the image box of its bounding sphere (one compiled pass), which
keeps the filter at ~1 ms instead of the ~10–20 ms of a second (segmentation) render. The
space hidden behind the arm is unknown and treated as free, as in Flacco et al. (one camera;
several cameras: it creates no hidden space, but only what another camera sees in front of a
return is free, :mod:`compare.sensing.fusion`).

**Static background** (table, floor): a depth image of the static geoms (group 0) is rendered
once; a pixel is removed when it is not nearer than that background by more than a margin,

.. math:: \text{remove } (u, v) \iff b(u, v) > 0 \;\wedge\; d(u, v) \ge b(u, v) - m_b - k\,\sigma(b)

so the table is never an obstacle while a person (or a hand on the table's edge, beyond
:math:`m_b`) is kept. On hardware the background is a depth frame captured without people.
"""

from __future__ import annotations

import mujoco
import numpy as np

from compare.sensing._frame_kernels import remove_near_geoms, zero_at_or_beyond
from compare.sensing.camera import DepthNoise, normalized_coordinates
from compare.sensing.exceptions import SensingError, UnknownSceneElement
from compare.sensing.frames import CameraModel, DepthFrame
from compare.sensing.renderer import ROBOT_VISUAL_GROUP, DepthCamera

_SUPPORTED = (
    mujoco.mjtGeom.mjGEOM_SPHERE,
    mujoco.mjtGeom.mjGEOM_CAPSULE,
    mujoco.mjtGeom.mjGEOM_CYLINDER,
    mujoco.mjtGeom.mjGEOM_BOX,
)


def subtree_bodies(model: mujoco.MjModel, root: int) -> np.ndarray:
    """Ids of ``root`` and all its descendants."""
    inside = np.zeros(model.nbody, dtype=bool)
    inside[root] = True
    for b in range(root + 1, model.nbody):  # parents come before children in MuJoCo
        inside[b] = inside[model.body_parentid[b]]
    return np.flatnonzero(inside)


class SelfFilter:
    """Blank the pixels that measure the arm (module docstring).

    Args:
        model: Scene model containing the arm.
        camera: The depth camera (intrinsics and pose in the base frame).
        margin_m: Inflation :math:`m` of the arm's geoms [m] (paper: inflated boxes).
        noise: Sensor noise, widening the margin by ``noise_allowance`` σ(d).
        noise_allowance: :math:`k`.
        root_body: Root body of the arm (its subtree is the arm); None = the subtree holding the
            model's first joint (the arm of a work cell: the person has no joints).
        geom_group: Group of the arm geoms that the camera sees (the visual ones).
    """

    def __init__(
        self,
        model: mujoco.MjModel,
        camera: CameraModel,
        margin_m: float = 0.03,
        noise: DepthNoise | None = None,
        noise_allowance: float = 5.0,
        root_body: str | None = None,
        geom_group: int = ROBOT_VISUAL_GROUP,
    ) -> None:
        if not margin_m >= 0.0:
            raise SensingError(f"self-filter margin must be >= 0, got {margin_m}")
        if root_body is None and model.njnt > 0:
            root_body = model.body(int(model.body_rootid[model.jnt_bodyid[0]])).name
        root = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, root_body or "")
        if root < 0:
            raise UnknownSceneElement("body", str(root_body), [model.body(i).name for i in range(model.nbody)])
        bodies = subtree_bodies(model, root)
        mask = np.isin(model.geom_bodyid, bodies) & (model.geom_group == geom_group)
        self.geom_ids = np.flatnonzero(mask)
        if self.geom_ids.size == 0:
            raise SensingError(f"no geoms of group {geom_group} under body '{root_body}'")
        self.model = model
        self.camera = camera
        self.margin_m = float(margin_m)
        self.noise = noise or DepthNoise()
        self.noise_allowance = float(noise_allowance)
        self._types = model.geom_type[self.geom_ids].copy()
        self._sizes = model.geom_size[self.geom_ids].copy()
        self._rbound = model.geom_rbound[self.geom_ids].copy()
        self._rbound[self._types == mujoco.mjtGeom.mjGEOM_SPHERE] = self._sizes[
            self._types == mujoco.mjtGeom.mjGEOM_SPHERE, 0
        ]
        self._exact = np.isin(self._types, _SUPPORTED)  # others: tested as their bounding sphere
        self._sizes32 = self._sizes.astype(np.float32)
        self._rbound32 = self._rbound.astype(np.float32)
        # The arm's joints: a private MjData computes geom poses from q alone (hardware, or q
        # at capture time).
        joints = np.flatnonzero(np.isin(model.jnt_bodyid, bodies))
        self.qpos_adr = model.jnt_qposadr[joints]
        self._data = mujoco.MjData(model)
        xn, yn = normalized_coordinates(camera)
        self._xn = xn.astype(np.float32)
        self._yn = yn.astype(np.float32)

    def _margin(self, depth: np.ndarray | float) -> np.ndarray | float:
        return self.margin_m + self.noise_allowance * self.noise.std_at(depth)

    def geom_poses_from_q(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World positions (n, 3) and rotation matrices (n, 3, 3) of the arm geoms at ``q``."""
        q = np.asarray(q, dtype=float)
        if q.shape != self.qpos_adr.shape or not np.all(np.isfinite(q)):
            raise SensingError(f"q must be {self.qpos_adr.size} finite joint positions, got {q!r}")
        self._data.qpos[self.qpos_adr] = q
        mujoco.mj_kinematics(self.model, self._data)
        return self.geom_poses(self._data)

    def geom_poses(self, data: mujoco.MjData) -> tuple[np.ndarray, np.ndarray]:
        """World positions (n, 3) and rotation matrices (n, 3, 3) of the arm geoms in ``data``."""
        return data.geom_xpos[self.geom_ids].copy(), data.geom_xmat[self.geom_ids].reshape(-1, 3, 3).copy()

    def pixel_boxes(self, centres: np.ndarray, width: int, height: int) -> np.ndarray:
        """Each geom's pixel box (v0, v1, u0, u1) around its sphere inflated by the margin; -1s: not in view.

        Args:
            centres: Geom centres in the sensor frame [m], shape (n, 3).
            width: Image width [px].
            height: Image height [px].
        """
        boxes = np.full((self.geom_ids.size, 4), -1, dtype=np.int64)
        for i, c in enumerate(centres):
            reach = float(self._rbound[i] + self._margin(max(c[2] + self._rbound[i], 0.0)))
            box = _sphere_box(self.camera, c, reach, width, height)
            if box is not None:
                boxes[i] = box
        return boxes

    def apply(self, frame: DepthFrame, q: np.ndarray | None = None, data: mujoco.MjData | None = None) -> DepthFrame:
        """A copy of ``frame`` without the arm's pixels (0 = removed).

        Args:
            frame: Depth frame (0/NaN = no return).
            q: Arm joint positions [rad] at capture time; or
            data: Simulation state at capture time (after ``mj_kinematics``).

        Returns:
            The filtered frame (a copy; NaN pixels stay NaN = no return).
        """
        depth = np.array(frame.depth_m, dtype=np.float32, copy=True)
        self.apply_inplace(depth, q=q, data=data)
        return DepthFrame(depth, frame.stamp_s, frame.camera)

    def apply_inplace(self, depth: np.ndarray, q: np.ndarray | None = None, data: mujoco.MjData | None = None) -> int:
        """Zero the arm's pixels of a float32 depth image in place (NaN pixels are left alone); return how many."""
        if (q is None) == (data is None):
            raise SensingError("pass exactly one of q (joint positions) or data (MuJoCo state)")
        pos, rot = self.geom_poses_from_q(q) if q is not None else self.geom_poses(data)  # type: ignore[arg-type]
        T = self.camera.transform_base_to_camera
        R_bc, t_bc = T[:3, :3], T[:3, 3]
        centres = (pos - t_bc) @ R_bc  # (n, 3) in the sensor frame
        rots = np.einsum("ji,njk->nik", R_bc, rot)  # geom axes in the sensor frame, (n, 3, 3)
        height, width = depth.shape
        return remove_near_geoms(
            depth,
            self.pixel_boxes(centres, width, height),
            centres.astype(np.float32),
            rots.astype(np.float32),
            self._types,
            self._sizes32,
            self._rbound32,
            self._exact,
            self._xn,
            self._yn,
            np.float32(self.margin_m),
            np.float32(self.noise_allowance),
            np.float32(self.noise.std_m),
            self.noise.proportional,
        )


def _sphere_box(cam: CameraModel, c: np.ndarray, r: float, width: int, height: int) -> tuple[int, int, int, int] | None:
    """Pixel box [v0, v1) x [u0, u1) covering the sphere (centre ``c`` in the sensor frame, radius r)."""
    z_far = c[2] + r
    if z_far <= cam.min_range_m * 0.5:
        return None
    z_near = max(c[2] - r, 1e-3)
    xs = (c[0] - r, c[0] + r)
    ys = (c[1] - r, c[1] + r)
    us = [cam.cx + cam.fx * x / z for x in xs for z in (z_near, z_far)]
    vs = [cam.cy + cam.fy * y / z for y in ys for z in (z_near, z_far)]
    u0, u1 = max(int(np.floor(min(us))), 0), min(int(np.ceil(max(us))) + 1, width)
    v0, v1 = max(int(np.floor(min(vs))), 0), min(int(np.ceil(max(vs))) + 1, height)
    if u0 >= u1 or v0 >= v1:
        return None
    return v0, v1, u0, u1


class StaticBackground:
    """Removes the static environment (table, floor) by comparison with a background depth image.

    Args:
        background_m: Depth of the static scene [m], shape (H, W); 0 = no return (nothing removed there).
        margin_m: :math:`m_b` [m]: a pixel must be this much nearer than the background to be kept.
        noise: Sensor noise, widening the margin by ``noise_allowance`` σ(b).
        noise_allowance: :math:`k`.
    """

    def __init__(
        self,
        background_m: np.ndarray,
        margin_m: float = 0.04,
        noise: DepthNoise | None = None,
        noise_allowance: float = 5.0,
    ) -> None:
        bg = np.nan_to_num(np.asarray(background_m, dtype=np.float32), nan=0.0)
        if bg.ndim != 2:
            raise SensingError(f"background must be an (H, W) image, got shape {bg.shape}")
        if not margin_m >= 0.0:
            raise SensingError(f"background margin must be >= 0, got {margin_m}")
        noise = noise or DepthNoise()
        threshold = bg - np.float32(margin_m) - np.float32(noise_allowance) * np.asarray(noise.std_at(bg), np.float32)
        # Pixels without background keep everything: threshold +inf.
        self.threshold_m = np.where(bg > 0, threshold, np.float32(np.inf)).astype(np.float32)
        self.background_m = bg
        self.margin_m = float(margin_m)

    @classmethod
    def capture(
        cls,
        camera: DepthCamera,
        model: mujoco.MjModel,
        margin_m: float = 0.04,
        noise: DepthNoise | None = None,
        noise_allowance: float = 5.0,
    ) -> StaticBackground:
        """Render the static geoms (group 0) of ``model`` with ``camera`` as the background.

        Capture after the camera is placed: the background belongs to one camera pose.
        """
        data = mujoco.MjData(model)
        mujoco.mj_kinematics(model, data)
        mujoco.mj_camlight(model, data)  # camera poses are not part of mj_kinematics
        return cls(camera.render_static(data), margin_m, noise, noise_allowance)

    def apply_inplace(self, depth: np.ndarray) -> None:
        """Zero the background pixels of a float32 depth image in place (NaN pixels are left alone)."""
        if depth.shape != self.threshold_m.shape:
            raise SensingError(f"frame shape {depth.shape} != background shape {self.threshold_m.shape}")
        zero_at_or_beyond(depth, self.threshold_m, depth)

    def without(self, depth: np.ndarray) -> np.ndarray:
        """A float32 copy of the depth image ``depth`` [m] without its background pixels."""
        depth = np.asarray(depth, dtype=np.float32)
        if depth.shape != self.threshold_m.shape:
            raise SensingError(f"frame shape {depth.shape} != background shape {self.threshold_m.shape}")
        out = np.empty_like(depth)
        zero_at_or_beyond(depth, self.threshold_m, out)
        return out

    def apply(self, frame: DepthFrame) -> DepthFrame:
        """A copy of ``frame`` without background pixels."""
        depth = np.array(frame.depth_m, dtype=np.float32, copy=True)
        self.apply_inplace(depth)
        return DepthFrame(depth, frame.stamp_s, frame.camera)

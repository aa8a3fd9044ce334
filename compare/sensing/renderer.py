r"""Simulated depth camera: MuJoCo offscreen depth rendering into a :class:`DepthFrame`.

Headless rendering needs an OpenGL backend: set ``MUJOCO_GL=egl`` (or ``osmesa``) before
``mujoco`` is imported. The camera renders on demand (the loop decides the rate, 30 Hz for the
Kinect) and reuses its GL context, scene and buffers between frames.

MuJoCo 4 renders with a reversed, floating-point depth buffer read as ``mjDEPTH_ZEROFAR``
(0 = far plane). The buffer value :math:`z \in [0, 1]` maps to the depth along the optical
axis (eye-space distance, not the Euclidean range of the pixel; checked against a plane in
``tests/compare/sensing/test_camera.py``) as

.. math:: d = \frac{f\, n}{(f - n)\, z + n}

with the near/far clipping distances :math:`n, f` (``visual/map`` znear, zfar times the model
extent). Pixels outside the valid range (including the background, rendered at the far plane)
become 0, i.e. "no return", as on the Kinect.
"""

from __future__ import annotations

import mujoco
import numpy as np
from OpenGL import GL

from compare.sensing._frame_kernels import depth_from_buffer
from compare.sensing.camera import DepthNoise, camera_id, camera_model_from_mujoco
from compare.sensing.exceptions import SensingError
from compare.sensing.frames import CameraModel, DepthFrame
from compare.sensing.noise_draws import shared_draws

STATIC_GROUP = 0
"""Geom group of the static environment (floor, table)."""
PERSON_GROUP = 1
"""Geom group of the person (the obstacles)."""
ROBOT_VISUAL_GROUP = 2
"""Geom group of the arm's visual geoms."""

_PLANE_BOX_HALF_THICKNESS_M = 0.005
_NO_PIXELS = np.empty((0, 0), dtype=np.float32)
"""Stands for "no noise draws" in :func:`depth_from_buffer`."""
_NO_MASK = np.empty((0, 0), dtype=bool)
"""Stands for "no dropout" in :func:`depth_from_buffer`."""


def planes_as_boxes(scene: mujoco.MjvScene, viewer_m: np.ndarray, reach_m: float) -> None:
    """Draw the plane geoms of ``scene`` as thin boxes: same image, half the llvmpipe render time.

    MuJoCo draws a plane as a finely subdivided grid (for lighting), which costs ~6 ms a frame
    for the floor under software rendering; a box whose top face is the plane gives the same
    depth (checked in the tests) with 12 triangles. An infinite plane becomes a box reaching
    ``reach_m`` beyond the viewer's distance to the plane's origin.

    Args:
        scene: A scene after ``mjv_updateScene``.
        viewer_m: Position of the viewer [m]. Shape (3,).
        reach_m: How far past the viewer an infinite plane must reach [m].
    """
    for i in range(scene.ngeom):
        g = scene.geoms[i]
        if g.type != mujoco.mjtGeom.mjGEOM_PLANE:
            continue
        normal = g.mat[:, 2]
        if g.size[0] > 0 and g.size[1] > 0:
            half_x, half_y = float(g.size[0]), float(g.size[1])
        else:  # infinite plane: cover everything the viewer can see
            half_x = half_y = float(np.linalg.norm(viewer_m - g.pos)) + reach_m
        g.type = mujoco.mjtGeom.mjGEOM_BOX
        g.size[:] = (half_x, half_y, _PLANE_BOX_HALF_THICKNESS_M)
        g.pos[:] = g.pos - _PLANE_BOX_HALF_THICKNESS_M * normal


def open_offscreen(
    model: mujoco.MjModel, width: int, height: int, font_scale: mujoco.mjtFontScale
) -> tuple[mujoco.GLContext, mujoco.MjrContext]:
    """A current GL context of ``width`` x ``height`` px and a MuJoCo render context drawing offscreen."""
    gl = mujoco.GLContext(width, height)
    gl.make_current()
    ctx = mujoco.MjrContext(model, font_scale)
    mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, ctx)
    return gl, ctx


def close_offscreen(gl: mujoco.GLContext, ctx: mujoco.MjrContext) -> None:
    """Free what :func:`open_offscreen` made (the render context first, with its GL context current)."""
    gl.make_current()
    ctx.free()
    gl.free()


class DepthCamera:
    """Renders depth frames of one MuJoCo camera, with optional noise and dropout.

    Args:
        model: Scene model (the camera's ``resolution`` must fit the offscreen buffer,
            ``visual/global offwidth/offheight``).
        camera: Camera name.
        noise: Noise and dropout added to every rendered frame.
        seed: Seed of the noise generator (``numpy.random.default_rng``).
        geom_groups: Geom groups drawn (default 0, 1, 2: environment, person, arm visual geoms).
        max_geom: Capacity of the MuJoCo scene.

    Attributes:
        camera: Intrinsics and pose (:class:`CameraModel`).
        noise: The noise model.
    """

    def __init__(
        self,
        model: mujoco.MjModel,
        camera: str = "depth_camera",
        noise: DepthNoise | None = None,
        seed: int = 0,
        geom_groups: tuple[int, ...] = (STATIC_GROUP, PERSON_GROUP, ROBOT_VISUAL_GROUP),
        max_geom: int = 2000,
    ) -> None:
        self.model = model
        self._cam_id = camera_id(model, camera)
        self._cam_name = camera
        self.camera: CameraModel = camera_model_from_mujoco(model, camera)
        self._moving = bool(model.cam_bodyid[self._cam_id] != 0 or model.cam_mode[self._cam_id] != 0)
        self.noise = noise or DepthNoise()
        w, h = self.camera.width, self.camera.height
        # The same draws as default_rng(seed) would give, shared with the cameras seeded alike.
        self._draws = (
            None if self.noise.is_zero else shared_draws(seed, (h, w), self.noise.std_m > 0.0, self.noise.dropout)
        )
        if w > model.vis.global_.offwidth or h > model.vis.global_.offheight:
            raise SensingError(
                f"camera '{camera}' is {w}x{h} px but the offscreen buffer is "
                f"{model.vis.global_.offwidth}x{model.vis.global_.offheight}: raise visual/global offwidth/offheight"
            )
        self._gl, ctx = open_offscreen(model, w, h, mujoco.mjtFontScale.mjFONTSCALE_100)
        self._ctx: mujoco.MjrContext | None = ctx
        ctx.readDepthMap = mujoco.mjtDepthMap.mjDEPTH_ZEROFAR
        self._scene = mujoco.MjvScene(model, maxgeom=max_geom)
        # Flat ID colours, no shadows/reflections/skybox: only the depth buffer matters.
        flags = self._scene.flags
        for flag in ("mjRND_SHADOW", "mjRND_REFLECTION", "mjRND_SKYBOX", "mjRND_FOG", "mjRND_HAZE"):
            flags[getattr(mujoco.mjtRndFlag, flag)] = 0
        flags[mujoco.mjtRndFlag.mjRND_SEGMENT] = 1
        flags[mujoco.mjtRndFlag.mjRND_IDCOLOR] = 1
        self._option = mujoco.MjvOption()
        self._option.geomgroup[:] = 0
        for g in geom_groups:
            self._option.geomgroup[g] = 1
        self._option.sitegroup[:] = 0
        self._mjv_camera = mujoco.MjvCamera()
        self._mjv_camera.type = mujoco.mjtCamera.mjCAMERA_FIXED
        self._mjv_camera.fixedcamid = self._cam_id
        self._rect = mujoco.MjrRect(0, 0, w, h)
        self._raw = np.empty((h, w), dtype=np.float32)
        extent = model.stat.extent
        near, far = float(model.vis.map.znear * extent), float(model.vis.map.zfar * extent)
        self._fn = np.float32(far * near)
        self._f_minus_n = np.float32(far - near)
        self._near = np.float32(near)
        if not near < self.camera.min_range_m:
            raise SensingError(f"near clipping plane {near:.3g} m must be closer than the camera range")
        if not far > self.camera.max_range_m:
            raise SensingError(f"far clipping plane {far:.3g} m must be beyond the camera range")

    def render(self, data: mujoco.MjData, stamp_s: float | None = None, noisy: bool = True) -> DepthFrame:
        """Render the current state of ``data`` (after ``mj_kinematics``, e.g. any ``mj_step``).

        Args:
            data: Simulation state.
            stamp_s: Frame time [s]; default ``data.time``.
            noisy: Apply the camera's noise and dropout.

        Returns:
            A new :class:`DepthFrame` (float32, metres along the optical axis, 0 = no return).
        """
        depth = self.render_depth(data, noisy=noisy)
        camera = camera_model_from_mujoco(self.model, self._cam_name, data) if self._moving else self.camera
        return DepthFrame(depth, float(data.time) if stamp_s is None else float(stamp_s), camera)

    __call__ = render

    def render_depth(
        self, data: mujoco.MjData, noisy: bool = True, option: mujoco.MjvOption | None = None
    ) -> np.ndarray:
        """The depth image [m] as a new float32 array of shape (H, W) (0 = no return)."""
        if self._ctx is None:
            raise SensingError("the depth camera is closed")
        self._gl.make_current()
        mujoco.mjv_updateScene(
            self.model,
            data,
            option or self._option,
            None,
            self._mjv_camera,
            mujoco.mjtCatBit.mjCAT_STATIC | mujoco.mjtCatBit.mjCAT_DYNAMIC,
            self._scene,
        )
        self._planes_as_boxes(data)
        # Only the depth buffer is read: no colour writes (the same depth, a quarter less raster work).
        GL.glColorMask(False, False, False, False)
        mujoco.mjr_render(self._rect, self._scene, self._ctx)
        mujoco.mjr_readPixels(None, self._raw, self._rect, self._ctx)
        normal, dropped = self._draws.next_frame() if noisy and self._draws is not None else (None, None)
        n, cam = self.noise, self.camera
        out = np.empty_like(self._raw)
        depth_from_buffer(
            self._raw,
            self._f_minus_n,
            self._near,
            self._fn,
            _NO_PIXELS if normal is None else normal,
            np.float32(n.std_m),
            n.proportional,
            _NO_MASK if dropped is None else dropped,
            np.float32(cam.min_range_m),
            np.float32(cam.max_range_m),
            out,
        )
        return out

    def render_static(self, data: mujoco.MjData) -> np.ndarray:
        """Noise-free depth of the static environment only (geom group 0) [m], shape (H, W)."""
        option = mujoco.MjvOption()
        option.geomgroup[:] = 0
        option.geomgroup[STATIC_GROUP] = 1
        option.sitegroup[:] = 0
        return self.render_depth(data, noisy=False, option=option)

    def _planes_as_boxes(self, data: mujoco.MjData) -> None:
        """Draw plane geoms as thin boxes (:func:`planes_as_boxes`) reaching past the camera's range."""
        planes_as_boxes(self._scene, data.cam_xpos[self._cam_id], 2.0 * self.camera.max_range_m)

    def close(self) -> None:
        """Free the GL resources (idempotent)."""
        if self._ctx is not None:
            close_offscreen(self._gl, self._ctx)
            self._ctx = None

    def __enter__(self) -> DepthCamera:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __del__(self) -> None:
        try:
            self.close()
        except Exception:  # interpreter shutdown: GL may already be gone
            pass

    def __repr__(self) -> str:
        c = self.camera
        return (
            f"DepthCamera({self._cam_name!r}, {c.width}x{c.height}, f=({c.fx:.1f}, {c.fy:.1f}), "
            f"c=({c.cx:.1f}, {c.cy:.1f}), range={c.min_range_m}-{c.max_range_m} m, noise={self.noise})"
        )

"""Frames of a replayed run: the methods side by side, drawn offscreen by MuJoCo.

Each frame holds one panel per method (equal widths): the work cell seen from the same viewpoint,
the arm at the method's step, the person at the frame's instant, the control points as spheres
coloured by their measured margin with a line to the closest point of the person, and the overlay
of :mod:`compare.replay.overlay`. One GL context draws everything (``MUJOCO_GL=egl`` headless).
Software rendering (llvmpipe) sets the look: a plain floor with grid lines instead of the
textured one, coarser capsules, no shadows, reflections or skybox.
"""

from __future__ import annotations

from pathlib import Path

import imageio.v3 as iio
import mujoco
import numpy as np

from compare.replay.exceptions import ReplayError
from compare.replay.overlay import OverlayStyle, PanelInfo, PanelSource, draw_panel, label_width_px, margin_colour
from compare.replay.run_data import ReplayRun
from compare.replay.scene import ReplayScene, ViewPoint, default_view
from compare.sensing.geometric_distance import closest_on_capsules
from compare.sensing.renderer import close_offscreen, open_offscreen, planes_as_boxes

MARKER_RADIUS_M = 0.035
"""Radius of a control point's sphere [m]."""
MESH_SLICES, MESH_STACKS = 16, 8
"""Tessellation of capsules, cylinders and spheres (MuJoCo's default 28, 16): a fifth less
software-rendering time, no visible facets at 720p."""
FLOOR_RGBA = (0.17, 0.22, 0.29, 1.0)
GRID_RGBA = np.array([0.42, 0.5, 0.6, 1.0], dtype=np.float32)
GRID_STEP_M, GRID_HALF_M = 0.5, 3.0
"""Floor grid: a line every 0.5 m out to 3 m from the arm's base."""
FLOOR_REACH_M = 2.5
"""How far the floor reaches beyond the view's look-at point [m]; past it, the background."""
_EYE, _ZERO = np.eye(3).ravel(), np.zeros(3)


class PanelRenderer:
    """Draws the methods of a run side by side into RGB frames (one offscreen GL context).

    Args:
        run: The loaded run.
        width: Frame width [px].
        height: Frame height [px].
        view: Viewpoint of every panel (default :func:`~compare.replay.scene.default_view`).
    """

    def __init__(self, run: ReplayRun, width: int, height: int, view: ViewPoint | None = None) -> None:
        self.run = run
        self.scene = ReplayScene(run)
        model = self.scene.model
        _prepare_model(model, width, height)
        self._grid = floor_grid(model)
        n = len(run.methods)
        edges = np.linspace(0, width, n + 1).round().astype(int)
        self.rects = [mujoco.MjrRect(int(a), 0, int(b - a), height) for a, b in zip(edges[:-1], edges[1:], strict=True)]
        self.full = mujoco.MjrRect(0, 0, width, height)
        scale = mujoco.mjtFontScale.mjFONTSCALE_150 if height >= 600 else mujoco.mjtFontScale.mjFONTSCALE_100
        self._gl, ctx = open_offscreen(model, width, height, scale)
        self._ctx: mujoco.MjrContext | None = ctx
        self._scn = mujoco.MjvScene(model, maxgeom=1000)
        for flag in ("mjRND_SHADOW", "mjRND_REFLECTION", "mjRND_SKYBOX", "mjRND_HAZE", "mjRND_FOG"):
            self._scn.flags[getattr(mujoco.mjtRndFlag, flag)] = 0  # costly in software, not needed to read the scene
        self._option = mujoco.MjvOption()
        self._option.sitegroup[:] = 0
        self._camera = mujoco.MjvCamera()
        self._sources = [PanelSource(run, m) for m in run.methods]
        activation = [th.safety_lower + th.activation_margin for th in run.obstacle_thresholds().values()]
        full_bar_m = max([run.config.sensor.rho_m, *(1.5 * a for a in activation)])
        self.style = OverlayStyle.for_height(height, full_bar_m, label_width_px(ctx, run.control_points))
        view_height = height - self.style.strip_px(len(run.control_points))
        self.view = view or default_view(run, self.scene.person, self.rects[0].width / view_height)
        self.view.apply(self._camera)
        self._rgb = np.empty((height, width, 3), dtype=np.uint8)

    def render(self, t: float) -> np.ndarray:
        """The frame at time ``t`` [s]: RGB, shape (H, W, 3), rows bottom-up (OpenGL order); reused buffer."""
        if self._ctx is None:
            raise ReplayError("the video renderer is closed")
        self._gl.make_current()
        rows = self.scene.set_time(t)
        infos = [source.info(row, t) for source, row in zip(self._sources, rows, strict=True)]
        points, closest = self._marker_points(infos, rows, t)
        for i, (rect, data, info) in enumerate(zip(self.rects, self.scene.datas, infos, strict=True)):
            mujoco.mjv_updateScene(
                self.scene.model, data, self._option, None, self._camera, mujoco.mjtCatBit.mjCAT_ALL, self._scn
            )
            planes_as_boxes(self._scn, np.asarray(self.view.lookat), FLOOR_REACH_M)
            self._add_grid()
            self._add_markers(info, points[i], closest[i])
            strip = self.style.strip_px(len(info.distances))
            view = mujoco.MjrRect(rect.left, rect.bottom + strip, rect.width, rect.height - strip)
            mujoco.mjr_render(view, self._scn, self._ctx)  # the bars' strip is not rendered in 3D
            draw_panel(self._ctx, rect, info, self.style)
        for rect in self.rects[1:]:
            mujoco.mjr_rectangle(mujoco.MjrRect(rect.left - 1, 0, 2, rect.height), 0.0, 0.0, 0.0, 1.0)
        mujoco.mjr_readPixels(self._rgb, None, self.full, self._ctx)
        return self._rgb

    def _add_grid(self) -> None:
        """The floor's grid lines (the floor itself is drawn plain: its texture is half the render time)."""
        scn = self._scn
        for a, b in self._grid:
            if scn.ngeom >= scn.maxgeom:
                return
            g = scn.geoms[scn.ngeom]
            mujoco.mjv_initGeom(g, mujoco.mjtGeom.mjGEOM_LINE, _ZERO, _ZERO, _EYE, GRID_RGBA)
            mujoco.mjv_connector(g, mujoco.mjtGeom.mjGEOM_LINE, 1.5, a, b)
            scn.ngeom += 1

    def _marker_points(self, infos: list[PanelInfo], rows: list[int], t: float) -> tuple[np.ndarray, np.ndarray]:
        """Control points [m] of every panel (P, K, 3) and their closest points on the person (P, K, 3)."""
        positions = []
        for info, method, row in zip(infos, self.run.methods, rows, strict=True):
            kin = self.run.robot.kinematics(method.q[row])
            positions.append([kin.frame_position(b.frame) for b in info.distances])
        points = np.array(positions, dtype=float).reshape(len(infos), -1, 3)
        caps = self.scene.person.capsule_ends([t])
        _, closest = closest_on_capsules(points.reshape(-1, 3), caps.a[0], caps.b[0], caps.radius)
        return points, closest.reshape(points.shape)

    def _add_markers(self, info: PanelInfo, points: np.ndarray, closest: np.ndarray) -> None:
        """Control point spheres coloured by margin, a line to the closest point of the person."""
        scn = self._scn
        for bar, p, c in zip(info.distances, points, closest, strict=True):
            if scn.ngeom + 2 > scn.maxgeom:
                break
            rgba = np.array([*margin_colour(bar.measured_m, bar.physical_m, bar.safety_m, bar.activation_m), 1.0])
            g = scn.geoms[scn.ngeom]
            mujoco.mjv_initGeom(g, mujoco.mjtGeom.mjGEOM_SPHERE, np.full(3, MARKER_RADIUS_M), p, _EYE, rgba)
            scn.ngeom += 1
            if bar.true_m <= self.run.config.sensor.rho_m:
                g = scn.geoms[scn.ngeom]
                mujoco.mjv_initGeom(g, mujoco.mjtGeom.mjGEOM_LINE, _ZERO, _ZERO, _EYE, rgba)
                mujoco.mjv_connector(g, mujoco.mjtGeom.mjGEOM_LINE, 3.0, p, c)
                scn.ngeom += 1

    def close(self) -> None:
        """Free the GL resources (idempotent)."""
        if self._ctx is not None:
            close_offscreen(self._gl, self._ctx)
            self._ctx = None

    def __enter__(self) -> PanelRenderer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _prepare_model(model: mujoco.MjModel, width: int, height: int) -> None:
    """Offscreen buffer of the frame size, coarser tessellation, untextured floor (software rendering)."""
    model.vis.global_.offwidth = max(width, model.vis.global_.offwidth)
    model.vis.global_.offheight = max(height, model.vis.global_.offheight)
    model.vis.quality.numslices, model.vis.quality.numstacks = MESH_SLICES, MESH_STACKS
    for g in np.flatnonzero(model.geom_type == mujoco.mjtGeom.mjGEOM_PLANE):
        mat = model.geom_matid[g]
        if mat >= 0:
            model.mat_texid[mat] = -1
            model.mat_rgba[mat] = FLOOR_RGBA
        model.geom_rgba[g] = FLOOR_RGBA


def floor_grid(model: mujoco.MjModel) -> list[tuple[np.ndarray, np.ndarray]]:
    """End points [m] of the grid lines drawn on the (lowest) floor plane, 1 mm above it."""
    planes = np.flatnonzero(model.geom_type == mujoco.mjtGeom.mjGEOM_PLANE)
    if planes.size == 0:
        return []
    z = float(np.min(model.geom_pos[planes, 2])) + 1e-3
    ticks = np.arange(-GRID_HALF_M, GRID_HALF_M + 1e-9, GRID_STEP_M)
    lines = []
    for k in ticks:
        lines.append((np.array([k, -GRID_HALF_M, z]), np.array([k, GRID_HALF_M, z])))
        lines.append((np.array([-GRID_HALF_M, k, z]), np.array([GRID_HALF_M, k, z])))
    return lines


def check_still_path(path: Path) -> Path:
    """``path`` if it names a ``.png`` file; raises :class:`ReplayError` otherwise."""
    path = Path(path)
    if path.suffix.lower() != ".png":
        raise ReplayError(f"--still writes a PNG image: give a .png file, got {path}")
    return path


def write_still(run: ReplayRun, path: Path, t: float, width: int = 1280, height: int = 720) -> None:
    """Render the frame at time ``t`` [s] into a PNG file."""
    path = check_still_path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with PanelRenderer(run, width, height) as renderer:
        rgb = renderer.render(t)[::-1]
        iio.imwrite(path, np.ascontiguousarray(rgb))

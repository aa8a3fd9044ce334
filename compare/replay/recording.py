"""A replayed run as a rerun recording (``.rrd``, opened with ``rerun FILE.rrd``).

One timeline, ``time`` (seconds of the run), for every method. Entities:

* ``world/scene``: the table and the other static geoms; ``world/cameras/<camera>``: each depth
  camera's pose and intrinsics (runs with depth sensing).
* ``world/person``: the person's capsules at every control step.
* ``world/<method>/arm/<body>``: each arm body's pose at every step, its visual geoms beneath.
* ``world/<method>/control_points``: the control points, coloured by their measured margin
  (:func:`compare.replay.overlay.margin_colour`).
* ``world/<method>/closest``: arrows from each control point to the closest point of the person
  (the true geometry), for the points within the sensing range ρ.
* ``world/<method>/depth/<camera>``: the foreground of the re-rendered depth frames at the camera
  rate (:mod:`compare.replay.depth`); ``world/cameras/<camera>/background``: the static scene.
* ``plots/distance/<frame>/<method>/measured`` and ``.../true`` [m], with the obstacle task's
  thresholds ``plots/distance/<frame>/{physical,safety,activation}``.
* ``plots/active/<method>/<task>``: 1 while the task is in the active set, else 0.
* ``plots/status/<method>`` (0 ok, 1 degraded, 2 failed) and ``plots/solve_time_us/<method>`` [µs].

A blueprint stored in the file shows the methods side by side in 3D above the time series.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable
from pathlib import Path

import mujoco
import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from compare.replay.depth import DepthClouds
from compare.replay.exceptions import ReplayError
from compare.replay.overlay import margin_colour
from compare.replay.run_data import MethodRun, ReplayRun
from compare.replay.scene import ReplayScene, closest_person_points, control_point_positions
from compare.sensing.renderer import PERSON_GROUP
from compare.sensing.scene import arm_qpos_addresses

APPLICATION_ID = "tpik-compare-replay"
TIMELINE = "time"
METHOD_COLOURS = ((31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40), (148, 103, 189), (140, 86, 75))
"""Colour of each method's series, in the order replayed (matplotlib's tab10)."""
DEPTH_COLOUR = (90, 200, 255)
"""Colour of the depth foreground points."""
VISIBLE_GROUPS = (0, 1, 2)
"""Geom groups drawn (environment, person, the arm's visual geoms), as in MuJoCo's viewer."""


def write_recording(
    run: ReplayRun,
    path: Path,
    progress: Callable[[str], None] | None = None,
    depth_stride_px: int | None = None,
) -> None:
    """Write the run's window as a rerun recording at ``path``.

    Args:
        run: The loaded run.
        path: Output file (``.rrd``; parent directories are created).
        progress: Called with the name of each part as it starts.
        depth_stride_px: Pixel stride of the depth clouds (default
            :data:`compare.replay.depth.DEFAULT_STRIDE_PX`); only for runs with depth sensing.

    Raises:
        ReplayError: Not an ``.rrd`` path.
    """
    path = check_recording_path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    say = progress or (lambda _part: None)
    scene = ReplayScene(run)
    rec = rr.RecordingStream(APPLICATION_ID, recording_id=f"{run.summary.get('scenario')}-{run.summary.get('seed')}")
    rec.save(path, default_blueprint=blueprint(run))
    try:
        say("scene")
        rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        _log_static_geoms(rec, scene.model, scene.datas[0])
        times = _window(run.methods[0], run)
        say("person")
        _log_person(rec, scene, times)
        for i, method in enumerate(run.methods):
            say(method.name)
            rows = _rows(method, run)
            _log_arm(rec, scene, i, rows)
            _log_control_points(rec, run, scene, method, rows)
            _log_series(rec, run, method, rows, METHOD_COLOURS[i % len(METHOD_COLOURS)])
        _log_thresholds(rec, run)
        if run.depth_sensing:
            say("depth")
            _log_depth(rec, run, scene, depth_stride_px)
    finally:
        rec.flush()
        rec.disconnect()


def check_recording_path(path: Path) -> Path:
    """``path`` if it names an ``.rrd`` file; raises :class:`ReplayError` otherwise."""
    path = Path(path)
    if path.suffix.lower() != ".rrd":
        raise ReplayError(f"--rerun writes a rerun recording: give a .rrd file, got {path}")
    return path


def blueprint(run: ReplayRun) -> rrb.Blueprint:
    """The methods side by side in 3D above tabs of time series (distances, activation, status)."""
    shared = ["+ /world/scene/**", "+ /world/person/**", "+ /world/cameras/**"]
    views_3d = [
        rrb.Spatial3DView(name=m.name, origin="/world", contents=[*shared, f"+ /world/{m.name}/**"])
        for m in run.methods
    ]
    distance = [rrb.TimeSeriesView(name=f"distance {f} [m]", origin=f"/plots/distance/{f}") for f in run.control_points]
    active = [rrb.TimeSeriesView(name=f"active set: {m.name}", origin=f"/plots/active/{m.name}") for m in run.methods]
    status = [
        rrb.TimeSeriesView(name="status (0 ok, 1 degraded, 2 failed)", origin="/plots/status"),
        rrb.TimeSeriesView(name="solve time [µs]", origin="/plots/solve_time_us"),
    ]
    tabs = rrb.Tabs(
        rrb.Grid(*distance, name="distances"),
        rrb.Grid(*active, name="activation"),
        rrb.Grid(*status, name="status and solve time"),
    )
    return rrb.Blueprint(rrb.Vertical(rrb.Horizontal(*views_3d), tabs, row_shares=[3, 2]), collapse_panels=True)


def _rows(method: MethodRun, run: ReplayRun) -> np.ndarray:
    """Indices of the method's steps inside the window."""
    return np.flatnonzero((method.t >= run.t_from - 1e-9) & (method.t < run.t_to - 1e-9))


def _window(method: MethodRun, run: ReplayRun) -> np.ndarray:
    rows = _rows(method, run)
    return method.t[rows] if rows.size else np.array([run.t_from])


def _time(t: np.ndarray) -> list[rr.TimeColumn]:
    return [rr.TimeColumn(TIMELINE, duration=np.asarray(t, dtype=float))]


def _xyzw(wxyz: np.ndarray) -> np.ndarray:
    """MuJoCo's (w, x, y, z) quaternions as rerun's (x, y, z, w). Shape (..., 4)."""
    return np.concatenate([wxyz[..., 1:], wxyz[..., :1]], axis=-1)


def _rgb(rgba: np.ndarray | tuple[float, ...]) -> np.ndarray:
    """Colours in [0, 1] as 8-bit values."""
    return (np.clip(np.asarray(rgba, dtype=float), 0.0, 1.0) * 255).round().astype(np.uint8)


def _geom_archetype(model: mujoco.MjModel, g: int) -> rr.AsComponents | None:
    """The rerun shape of geom ``g`` in its own frame (None for planes and other unsupported types)."""
    size = model.geom_size[g]
    colour = _rgb(model.mat_rgba[model.geom_matid[g]] if model.geom_matid[g] >= 0 else model.geom_rgba[g])
    kind = model.geom_type[g]
    solid = rr.components.FillMode.Solid
    if kind == mujoco.mjtGeom.mjGEOM_CAPSULE:
        return rr.Capsules3D(lengths=[2 * size[1]], radii=[size[0]], translations=[[0, 0, -size[1]]], colors=[colour])
    if kind == mujoco.mjtGeom.mjGEOM_CYLINDER:
        return rr.Cylinders3D(lengths=[2 * size[1]], radii=[size[0]], colors=[colour], fill_mode=solid)
    if kind == mujoco.mjtGeom.mjGEOM_BOX:
        return rr.Boxes3D(half_sizes=[size], colors=[colour], fill_mode=solid)
    if kind in (mujoco.mjtGeom.mjGEOM_SPHERE, mujoco.mjtGeom.mjGEOM_ELLIPSOID):
        half = [size[0]] * 3 if kind == mujoco.mjtGeom.mjGEOM_SPHERE else size
        return rr.Ellipsoids3D(half_sizes=[half], colors=[colour], fill_mode=solid)
    if kind == mujoco.mjtGeom.mjGEOM_MESH:
        mesh = model.geom_dataid[g]
        v0, nv = model.mesh_vertadr[mesh], model.mesh_vertnum[mesh]
        f0, nf = model.mesh_faceadr[mesh], model.mesh_facenum[mesh]
        return rr.Mesh3D(
            vertex_positions=model.mesh_vert[v0 : v0 + nv],
            triangle_indices=model.mesh_face[f0 : f0 + nf],
            albedo_factor=colour,
        )
    return None


def _log_geoms(rec: rr.RecordingStream, model: mujoco.MjModel, parent: str, geoms: Iterable[int | np.integer]) -> None:
    """Each geom statically under ``parent``, placed in its body's frame."""
    for g in geoms:
        shape = _geom_archetype(model, int(g))
        if shape is None or model.geom_group[g] not in VISIBLE_GROUPS:
            continue
        path = f"{parent}/{model.geom(g).name or f'geom_{g}'}"
        rec.log(
            path,
            rr.Transform3D(translation=model.geom_pos[g], quaternion=rr.Quaternion(xyzw=_xyzw(model.geom_quat[g]))),
            static=True,
        )
        rec.log(path, shape, static=True)


def _arm_bodies(model: mujoco.MjModel) -> list[int]:
    """Bodies of the arm (the subtree of the model's first joint)."""
    root = model.body_rootid[model.jnt_bodyid[0]]
    return [b for b in range(model.nbody) if model.body_rootid[b] == root]


def _log_static_geoms(rec: rr.RecordingStream, model: mujoco.MjModel, data: mujoco.MjData) -> None:
    """The work cell's fixed geoms (table, ...), each body at its pose."""
    arm = set(_arm_bodies(model))
    for b in range(model.nbody):
        if b in arm or model.body_mocapid[b] >= 0:
            continue
        geoms = [g for g in np.flatnonzero(model.geom_bodyid == b) if model.geom_group[g] != PERSON_GROUP]
        if not geoms:
            continue
        parent = f"world/scene/{model.body(b).name or f'body_{b}'}"
        rec.log(
            parent,
            rr.Transform3D(translation=data.xpos[b], quaternion=rr.Quaternion(xyzw=_xyzw(data.xquat[b]))),
            static=True,
        )
        _log_geoms(rec, model, parent, geoms)


def _log_person(rec: rr.RecordingStream, scene: ReplayScene, times: np.ndarray) -> None:
    """The person's capsules at ``times`` [s] (a capsule of length 0 for the head)."""
    caps = scene.person.capsule_ends(times)
    model = scene.model
    colours = _rgb(np.array([model.geom_rgba[model.geom(name).id] for name in caps.names]))
    axis = caps.b - caps.a
    length = np.linalg.norm(axis, axis=-1)
    quat = _z_to(axis.reshape(-1, 3))
    n, g = length.shape
    rec.send_columns(
        "world/person",
        indexes=_time(times),
        columns=rr.Capsules3D.columns(
            lengths=length.reshape(-1),
            radii=np.tile(caps.radius, n),
            translations=caps.a.reshape(-1, 3),
            quaternions=quat,
            colors=np.tile(colours, (n, 1)),
        ).partition([g] * n),
    )


def _z_to(v: np.ndarray) -> np.ndarray:
    """Quaternions (x, y, z, w) of the shortest rotations taking +z to each row of ``v`` (N, 3)."""
    n = np.linalg.norm(v, axis=1)
    u = v / np.maximum(n, 1e-12)[:, None]
    q = np.column_stack([-u[:, 1], u[:, 0], np.zeros(len(u)), 1.0 + u[:, 2]])
    down = q[:, 3] < 1e-9
    q[down] = (1.0, 0.0, 0.0, 0.0)  # straight down: half a turn about x
    q[n < 1e-12] = (0.0, 0.0, 0.0, 1.0)
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def _log_arm(rec: rr.RecordingStream, scene: ReplayScene, index: int, rows: np.ndarray) -> None:
    """Method ``index``'s arm: its bodies' poses at each step, their visual geoms once."""
    model, method = scene.model, scene.run.methods[index]
    data = mujoco.MjData(model)
    address = arm_qpos_addresses(model)
    bodies = [b for b in _arm_bodies(model) if b != 0]
    pos = np.empty((len(rows), len(bodies), 3))
    quat = np.empty((len(rows), len(bodies), 4))
    for i, k in enumerate(rows):
        data.qpos[address] = method.q[k]
        mujoco.mj_kinematics(model, data)
        pos[i], quat[i] = data.xpos[bodies], data.xquat[bodies]
    for j, b in enumerate(bodies):
        path = f"world/{method.name}/arm/{model.body(b).name or f'body_{b}'}"
        rec.send_columns(
            path,
            indexes=_time(method.t[rows]),
            columns=rr.Transform3D.columns(translation=pos[:, j], quaternion=_xyzw(quat[:, j])),
        )
        _log_geoms(rec, model, path, np.flatnonzero(model.geom_bodyid == b))


def _log_control_points(
    rec: rr.RecordingStream, run: ReplayRun, scene: ReplayScene, method: MethodRun, rows: np.ndarray
) -> None:
    """The control points coloured by margin; arrows to the person's closest points within ρ."""
    frames = run.control_points
    if not frames or rows.size == 0:
        return
    t = method.t[rows]
    points = control_point_positions(run, method.q[rows])  # (T, K, 3)
    true, closest = closest_person_points(scene.person, t, points)
    limits = run.obstacle_thresholds()
    colours = np.empty(points.shape, dtype=np.uint8)
    for k, frame in enumerate(frames):
        th = limits.get(frame)
        lo = (th.physical_lower, th.safety_lower, th.safety_lower + th.activation_margin) if th else (math.nan,) * 3
        measured = method.column(f"dist_meas:{frame}")[rows]
        colours[:, k] = [_rgb(margin_colour(float(d), *lo)) for d in measured]
    n, kk = len(t), len(frames)
    rec.send_columns(
        f"world/{method.name}/control_points",
        indexes=_time(t),
        columns=rr.Points3D.columns(
            positions=points.reshape(-1, 3), colors=colours.reshape(-1, 3), radii=np.full(n * kk, 0.03)
        ).partition([kk] * n),
    )
    near = true <= run.config.sensor.rho_m
    rec.send_columns(
        f"world/{method.name}/closest",
        indexes=_time(t),
        columns=rr.Arrows3D.columns(
            origins=points[near], vectors=(closest - points)[near], colors=colours[near]
        ).partition(near.sum(axis=1)),
    )


def _scalars(
    rec: rr.RecordingStream, path: str, t: np.ndarray, values: np.ndarray, name: str, colour: Iterable[int]
) -> None:
    values = np.where(np.isfinite(values), values, np.nan)
    rec.log(path, rr.SeriesLines(names=[name], colors=[list(colour)]), static=True)
    rec.send_columns(path, indexes=_time(t), columns=rr.Scalars.columns(scalars=values))


def _log_series(
    rec: rr.RecordingStream, run: ReplayRun, method: MethodRun, rows: np.ndarray, colour: tuple[int, int, int]
) -> None:
    """Distances, activation, status and solve time of one method."""
    t, name = method.t[rows], method.name
    faint = tuple(int(0.55 * c + 0.45 * 255) for c in colour)
    for frame in run.control_points:
        base = f"plots/distance/{frame}/{name}"
        _scalars(rec, f"{base}/measured", t, method.column(f"dist_meas:{frame}")[rows], f"{name} measured", colour)
        _scalars(rec, f"{base}/true", t, method.column(f"dist_true:{frame}")[rows], f"{name} true", faint)
    for task in run.set_tasks:
        column = f"active:{task.name}"
        if column in method.steps.columns:
            on = method.steps[column].fillna(False).to_numpy(dtype=float)[rows]
            _scalars(rec, f"plots/active/{name}/{task.name}", t, on, task.name, colour)
    _scalars(rec, f"plots/status/{name}", t, method.status_codes()[rows], name, colour)
    _scalars(rec, f"plots/solve_time_us/{name}", t, method.column("solve_time_us")[rows], name, colour)


def _log_thresholds(rec: rr.RecordingStream, run: ReplayRun) -> None:
    """Each control point's thresholds as constant lines over the window."""
    ends = np.array([run.t_from, run.t_to])
    for frame, th in run.obstacle_thresholds().items():
        levels = {
            "physical": (th.physical_lower, (120, 0, 0)),
            "safety": (th.safety_lower, (230, 30, 25)),
            "activation": (th.safety_lower + th.activation_margin, (255, 160, 15)),
        }
        for level, (value, colour) in levels.items():
            if math.isfinite(value):
                _scalars(rec, f"plots/distance/{frame}/{level}", ends, np.full(2, value), level, colour)


def _log_depth(rec: rr.RecordingStream, run: ReplayRun, scene: ReplayScene, stride_px: int | None) -> None:
    """Each camera's pose and background once; each method's foreground cloud at the camera rate."""
    clouds = DepthClouds(scene.model, run) if stride_px is None else DepthClouds(scene.model, run, stride_px)
    try:
        for c, (name, camera) in enumerate(zip(clouds.names, clouds.camera_models(), strict=True)):
            T = camera.transform_base_to_camera
            rec.log(f"world/cameras/{name}", rr.Transform3D(translation=T[:3, 3], mat3x3=T[:3, :3]), static=True)
            rec.log(
                f"world/cameras/{name}",
                rr.Pinhole(
                    focal_length=[camera.fx, camera.fy],
                    principal_point=[camera.cx, camera.cy],
                    resolution=[camera.width, camera.height],
                    image_plane_distance=0.2,
                ),
                static=True,
            )
            background = clouds.background(c, scene.datas[0])
            rec.log(
                f"world/cameras/{name}/background",
                rr.Points3D(background, colors=[150, 150, 150], radii=0.004),
                static=True,
            )
            rate = clouds.rates_hz[c]
            times = run.t_from + np.arange(max(1, math.floor((run.t_to - run.t_from) * rate))) / rate
            for i, method in enumerate(run.methods):
                _log_method_depth(rec, scene, clouds, c, i, times, f"world/{method.name}/depth/{name}")
    finally:
        clouds.close()


def _log_method_depth(
    rec: rr.RecordingStream,
    scene: ReplayScene,
    clouds: DepthClouds,
    camera: int,
    method: int,
    times: np.ndarray,
    path: str,
) -> None:
    data = scene.datas[method]
    chunks = []
    for t in times:
        scene.pose(method, float(t))
        chunks.append(clouds.foreground(camera, data).astype(np.float32))
    sizes = [len(c) for c in chunks]
    positions = np.concatenate(chunks) if chunks else np.empty((0, 3), np.float32)
    columns = rr.Points3D.columns(
        positions=positions, colors=np.tile(DEPTH_COLOUR, (len(positions), 1)), radii=np.full(len(positions), 0.005)
    )
    rec.send_columns(path, indexes=_time(times), columns=columns.partition(sizes))

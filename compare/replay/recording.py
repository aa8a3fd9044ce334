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
from compare.replay.rerun_series import METHOD_COLOURS, log_series, log_thresholds, time_column
from compare.replay.rerun_shapes import VISIBLE_GROUPS, arm_bodies, geom_archetype, quat_z_to, rgb8, xyzw
from compare.replay.run_data import MethodRun, ReplayRun
from compare.replay.scene import ReplayScene, closest_person_points, control_point_positions
from compare.sensing.renderer import PERSON_GROUP
from compare.sensing.scene import arm_qpos_addresses

APPLICATION_ID = "tpik-compare-replay"
DEPTH_COLOUR = (90, 200, 255)
"""Colour of the depth foreground points."""


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
            log_series(rec, run, method, rows, METHOD_COLOURS[i % len(METHOD_COLOURS)])
        log_thresholds(rec, run)
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


def _log_geoms(rec: rr.RecordingStream, model: mujoco.MjModel, parent: str, geoms: Iterable[int | np.integer]) -> None:
    """Each geom statically under ``parent``, placed in its body's frame."""
    for g in geoms:
        shape = geom_archetype(model, int(g))
        if shape is None or model.geom_group[g] not in VISIBLE_GROUPS:
            continue
        path = f"{parent}/{model.geom(g).name or f'geom_{g}'}"
        rec.log(
            path,
            rr.Transform3D(translation=model.geom_pos[g], quaternion=rr.Quaternion(xyzw=xyzw(model.geom_quat[g]))),
            static=True,
        )
        rec.log(path, shape, static=True)


def _log_static_geoms(rec: rr.RecordingStream, model: mujoco.MjModel, data: mujoco.MjData) -> None:
    """The work cell's fixed geoms (table, ...), each body at its pose."""
    arm = set(arm_bodies(model))
    for b in range(model.nbody):
        if b in arm or model.body_mocapid[b] >= 0:
            continue
        geoms = [g for g in np.flatnonzero(model.geom_bodyid == b) if model.geom_group[g] != PERSON_GROUP]
        if not geoms:
            continue
        parent = f"world/scene/{model.body(b).name or f'body_{b}'}"
        rec.log(
            parent,
            rr.Transform3D(translation=data.xpos[b], quaternion=rr.Quaternion(xyzw=xyzw(data.xquat[b]))),
            static=True,
        )
        _log_geoms(rec, model, parent, geoms)


def _log_person(rec: rr.RecordingStream, scene: ReplayScene, times: np.ndarray) -> None:
    """The person's capsules at ``times`` [s] (a capsule of length 0 for the head)."""
    caps = scene.person.capsule_ends(times)
    model = scene.model
    colours = rgb8(np.array([model.geom_rgba[model.geom(name).id] for name in caps.names]))
    axis = caps.b - caps.a
    length = np.linalg.norm(axis, axis=-1)
    quat = quat_z_to(axis.reshape(-1, 3))
    n, g = length.shape
    rec.send_columns(
        "world/person",
        indexes=time_column(times),
        columns=rr.Capsules3D.columns(
            lengths=length.reshape(-1),
            radii=np.tile(caps.radius, n),
            translations=caps.a.reshape(-1, 3),
            quaternions=quat,
            colors=np.tile(colours, (n, 1)),
        ).partition([g] * n),
    )


def _log_arm(rec: rr.RecordingStream, scene: ReplayScene, index: int, rows: np.ndarray) -> None:
    """Method ``index``'s arm: its bodies' poses at each step, their visual geoms once."""
    model, method = scene.model, scene.run.methods[index]
    data = mujoco.MjData(model)
    address = arm_qpos_addresses(model)
    bodies = [b for b in arm_bodies(model) if b != 0]
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
            indexes=time_column(method.t[rows]),
            columns=rr.Transform3D.columns(translation=pos[:, j], quaternion=xyzw(quat[:, j])),
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
        colours[:, k] = [rgb8(margin_colour(float(d), *lo)) for d in measured]
    n, kk = len(t), len(frames)
    rec.send_columns(
        f"world/{method.name}/control_points",
        indexes=time_column(t),
        columns=rr.Points3D.columns(
            positions=points.reshape(-1, 3), colors=colours.reshape(-1, 3), radii=np.full(n * kk, 0.03)
        ).partition([kk] * n),
    )
    near = true <= run.config.sensor.rho_m
    rec.send_columns(
        f"world/{method.name}/closest",
        indexes=time_column(t),
        columns=rr.Arrows3D.columns(
            origins=points[near], vectors=(closest - points)[near], colors=colours[near]
        ).partition(near.sum(axis=1)),
    )


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
    rec.send_columns(path, indexes=time_column(times), columns=columns.partition(sizes))

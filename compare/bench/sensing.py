"""Sensing benchmark: depth rendering, self-filter and depth-space distance per 512×424 frame.

Case ``512x424-rho0.5``: the work cell with the arm at ``home`` and the person stepped in,
reaching for the wrist (every control point has the person within ρ = 0.5 m). Stages, each
timed on the same frame:

* ``depth-render``: MuJoCo offscreen depth render + conversion to metres (no noise);
* ``self-filter``: static-background removal + arm removal (inflated geoms);
* ``depth-distance``: depth-space distance of the 3 control points (Flacco, sec. III);
* ``depth-kdtree-baseline``: brute force on the same filtered frame: every valid pixel to a
  base-frame point, ``scipy.spatial.cKDTree`` build and 3 nearest-point queries;
* ``geometric-distance``: the no-render mode (capsule geometry), for sweeps.

Case ``2x512x424-rho0.5``: the same scene seen by the two cameras of
``configs/case1_two_cameras.toml`` (the second on the opposite side of the cell, behind the
person: every control point lies in that camera's shadow of the person, so the fusion has work
to do). Each row is timed alternating call by call with its one-camera counterpart on the same
frames, by wall clock and by process CPU time (``ratio_vs_one_camera``,
``cpu_ratio_vs_one_camera``, ``cpu_median_us``):

* ``depth-distance``: per-camera distances of the 3 control points and their fusion
  (:mod:`compare.sensing.fusion`), on filtered frames;
* ``depth-sensing-step``: what the loop's sensing update costs per frame: both filters and the
  fused distance (case ``512x424-rho0.5``: one camera's filter and distance);
* ``depth-frame``: a whole frame, render included, against the 33 ms frame budget of a 30 Hz
  camera (``frame_budget_ms``).

Run: ``MUJOCO_GL=egl .venv/bin/python -m compare.bench.sensing [repeats]``.
"""

from __future__ import annotations

import math
import os
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

import mujoco  # noqa: E402
import numpy as np  # noqa: E402
from scipy.spatial import cKDTree  # noqa: E402

import robots  # noqa: E402
from compare.arguments import ArgumentParser, positive_int  # noqa: E402
from compare.bench.occlusion import cameras_from_config  # noqa: E402
from compare.bench.timing import BenchRow, summarize, time_calls  # noqa: E402
from compare.sensing import (  # noqa: E402
    DepthPipeline,
    DepthRig,
    DepthSensingSettings,
    GeometricDistance,
    Person,
    PersonKeyframe,
    control_point_positions,
    load_rig_workcell,
    load_workcell,
    make_data,
    point_cloud,
    valid_fraction,
)
from compare.versions import versions  # noqa: E402

CASE = "512x424-rho0.5"
CASE_TWO = "2x512x424-rho0.5"
RHO_M = 0.5
FRAME_BUDGET_MS = 1e3 / 30.0
TWO_CAMERA_CONFIG = Path(__file__).resolve().parents[2] / "configs" / "case1_two_cameras.toml"


def _bench_scene(
    robot: robots.Robot,
    model: mujoco.MjModel | None = None,
) -> tuple[mujoco.MjModel, mujoco.MjData, dict[str, np.ndarray], np.ndarray]:
    """Work cell at ``home``, the person 0.7 m from the base reaching past the hand (all 3 points in range)."""
    model = load_workcell(robot.name) if model is None else model
    data = make_data(model)
    q = np.array(data.qpos[: robot.nq])
    points = control_point_positions(robot.kinematics(q), robot.control_points)
    hand = robot.control_points[-1]
    rx, ry, rz = (float(v) for v in points[hand] + np.array([0.05, 0.25, 0.0]))
    reach = (rx, ry, rz)
    person = Person(model, [PersonKeyframe(0.0, (0.05, 0.7), yaw=-math.pi / 2, right_hand=reach)])
    person.apply(0.0, data)
    mujoco.mj_forward(model, data)
    return model, data, points, q


def run_sensing_bench(repeats: int = 200, robot: robots.Robot | None = None) -> list[BenchRow]:
    """Time the sensing stages on the case ``512x424-rho0.5`` (module docstring).

    Args:
        repeats: Timed calls per stage (after warm-up).
        robot: The arm in the work cell (default :data:`robots.DEFAULT_ROBOT`).

    Returns:
        Rows ``depth-render``, ``self-filter``, ``depth-distance``, ``depth-kdtree-baseline``,
        ``geometric-distance``; ``extra`` holds pixel counts, the speed-up of the depth-space
        distance over the baseline and the whole pipeline's median per frame.
    """
    model, data, points, q = _bench_scene(robot or robots.load(robots.DEFAULT_ROBOT))
    pipe = DepthPipeline(model, DepthSensingSettings(rho_m=RHO_M))
    try:
        frame = pipe.render(data)
        vf = valid_fraction(frame)
        render_us = time_calls(lambda: pipe.render(data), repeats, warmup=5)
        filter_us = time_calls(lambda: pipe.filter(frame, q=q), repeats, warmup=5)
        filtered = pipe.filter(frame, q=q)
        result = pipe.distance.compute(filtered, points, vf)
        targets = np.array(list(points.values()))

        def distance() -> object:
            return pipe.distance.compute(filtered, points, vf)

        def kdtree() -> tuple[np.ndarray, np.ndarray]:
            cloud, _ = point_cloud(filtered)
            return cKDTree(cloud).query(targets)

        kd_dist, _ = kdtree()
        distance_us, kdtree_us = _interleaved(distance, kdtree, repeats)
    finally:
        pipe.close()
    geometric = GeometricDistance(model, rho_m=RHO_M)
    truth = geometric.compute(data, points)
    geometric_us = time_calls(lambda: geometric.compute(data, points), repeats)

    n_points = int(np.count_nonzero(filtered.depth_m > 0))
    depth_d = np.array([result.readings[n].distance_m for n in points])
    true_d = np.array([truth.readings[n].distance_m for n in points])
    med = {k: float(np.median(v)) for k, v in (("r", render_us), ("f", filter_us), ("d", distance_us))}
    rows = [
        summarize("depth-render", CASE, render_us, pixels=float(frame.depth_m.size), valid_fraction=vf),
        summarize("self-filter", CASE, filter_us, foreground_pixels=float(n_points)),
        summarize(
            "depth-distance",
            CASE,
            distance_us,
            pixels_visited=float(result.pixels_visited),
            speedup_vs_kdtree=float(np.median(kdtree_us)) / med["d"],
            pipeline_median_us=med["r"] + med["f"] + med["d"],
            max_error_vs_geometry_m=float(np.max(np.abs(depth_d - true_d))),
        ),
        summarize(
            "depth-kdtree-baseline",
            CASE,
            kdtree_us,
            cloud_points=float(n_points),
            max_diff_vs_depth_distance_m=float(np.max(np.abs(kd_dist - depth_d))),
        ),
        summarize("geometric-distance", CASE, geometric_us, control_points=float(len(points))),
    ]
    return rows + run_two_camera_bench(repeats)


def run_two_camera_bench(repeats: int = 200, robot: robots.Robot | None = None) -> list[BenchRow]:
    """Time one camera against the two of ``configs/case1_two_cameras.toml`` on the same scene (module docstring).

    Returns:
        Rows ``depth-distance`` (case ``2x512x424-rho0.5``), ``depth-sensing-step`` and
        ``depth-frame`` (both cases); the two-camera rows carry ``ratio_vs_one_camera`` (wall
        medians) and ``cpu_ratio_vs_one_camera`` (process CPU time: the one that holds on a
        shared machine), from calls alternating with the one-camera counterpart.
    """
    cameras = cameras_from_config(TWO_CAMERA_CONFIG)
    robot = robot or robots.load(robots.DEFAULT_ROBOT)
    model, data, points, q = _bench_scene(robot, load_rig_workcell(robot.name, cameras))
    settings = [
        DepthSensingSettings(rho_m=RHO_M, camera=c.name, seed=i, robot_root_body=robot.base_body)
        for i, c in enumerate(cameras)
    ]
    rig = DepthRig(model, settings)
    one = rig.pipelines[0]
    try:
        frames = rig.render(data)
        vfs = [valid_fraction(f) for f in frames]
        filtered = rig.filter(frames, q=q)
        fused = rig.fusion.compute(filtered, points, vfs, raw_frames=frames)
        samples = rig.fusion.last_samples
        dist = _paired(
            lambda: one.distance.compute(filtered[0], points, vfs[0]),
            lambda: rig.fusion.compute(filtered, points, vfs, raw_frames=frames),
            repeats,
        )
        step = _paired(
            lambda: one.distance.compute(one.filter(frames[0], q=q), points, vfs[0]),
            lambda: rig.fusion.compute(rig.filter(frames, q=q), points, vfs, raw_frames=frames),
            max(20, repeats // 4),
        )
        frame = _paired(
            lambda: one.process(one.render(data), points, q=q),
            lambda: rig.process(rig.render(data), points, q=q),
            max(20, repeats // 10),
        )
    finally:
        rig.close()
    truth = GeometricDistance(model, rho_m=RHO_M).compute(data, points)
    diffs = [fused.readings[n].distance_m - truth.readings[n].distance_m for n in points]
    budget = {"frame_budget_ms": FRAME_BUDGET_MS}
    return [
        summarize(
            "depth-distance",
            CASE_TWO,
            dist.wall_b,
            **dist.ratios(),
            one_camera_median_us=float(np.median(dist.wall_a)),
            fusion_samples=float(samples),
            occluded_readings=float(sum(r.occluded for r in fused.readings.values())),
            max_error_vs_geometry_m=float(max(abs(d) for d in diffs)),
            max_over_estimate_vs_geometry_m=float(max(diffs)),
        ),
        summarize("depth-sensing-step", CASE, step.wall_a, cpu_median_us=float(np.median(step.cpu_a))),
        summarize(
            "depth-sensing-step", CASE_TWO, step.wall_b, cpu_median_us=float(np.median(step.cpu_b)), **step.ratios()
        ),
        summarize("depth-frame", CASE, frame.wall_a, cpu_median_us=float(np.median(frame.cpu_a)), **budget),
        summarize(
            "depth-frame",
            CASE_TWO,
            frame.wall_b,
            cpu_median_us=float(np.median(frame.cpu_b)),
            **frame.ratios(),
            **budget,
        ),
    ]


@dataclass
class _Pair:
    """Wall and process-CPU times [µs] of two functions called alternately."""

    wall_a: np.ndarray
    wall_b: np.ndarray
    cpu_a: np.ndarray
    cpu_b: np.ndarray

    def ratios(self) -> dict[str, float]:
        """B over A: ``ratio_vs_one_camera`` (wall medians) and ``cpu_ratio_vs_one_camera`` (CPU medians)."""
        return {
            "ratio_vs_one_camera": float(np.median(self.wall_b) / np.median(self.wall_a)),
            "cpu_ratio_vs_one_camera": float(np.median(self.cpu_b) / np.median(self.cpu_a)),
        }


def _paired(fn_a: Callable[[], object], fn_b: Callable[[], object], repeats: int, warmup: int = 10) -> _Pair:
    """Call A and B alternately ``repeats`` times each, timing wall clock and this process's CPU time.

    On a shared machine the wall clock also counts the time other jobs hold the cores; the
    process CPU time (every thread, the software renderer's included) counts only the work done,
    so its ratio is the one to trust there.
    """
    for _ in range(warmup):
        fn_a()
        fn_b()
    out = np.empty((4, repeats))
    wall, cpu = time.perf_counter_ns, time.process_time_ns
    for i in range(repeats):
        for j, fn in ((0, fn_a), (1, fn_b)):
            w0, c0 = wall(), cpu()
            fn()
            out[j, i] = (wall() - w0) * 1e-3
            out[2 + j, i] = (cpu() - c0) * 1e-3
    return _Pair(out[0], out[1], out[2], out[3])


def _interleaved(
    fn_a: Callable[[], object], fn_b: Callable[[], object], repeats: int, block: int = 10
) -> tuple[np.ndarray, np.ndarray]:
    """Time two functions in alternating blocks of ``block`` calls, so both see the same machine load."""
    time_calls(fn_a, 1, warmup=20)
    time_calls(fn_b, 1, warmup=20)
    a, b = [], []
    for _ in range(max(1, repeats // block)):
        a.append(time_calls(fn_a, block, warmup=0))
        b.append(time_calls(fn_b, block, warmup=0))
    return np.concatenate(a), np.concatenate(b)


def format_table(rows: list[BenchRow]) -> str:
    """Markdown table of the rows."""
    lines = ["| stage | case | median [ms] | p95 [ms] | samples | notes |", "|---|---|---:|---:|---:|---|"]
    for r in rows:
        notes = ", ".join(f"{k}={v:.4g}" for k, v in r.extra.items())
        lines.append(
            f"| {r.name} | {r.case} | {r.median_us / 1e3:.3f} | {r.p95_us / 1e3:.3f} | {r.samples} | {notes} |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    """Print the sensing table (``python -m compare.bench.sensing [REPEATS]``; ``--help``)."""
    parser = ArgumentParser(
        prog="python -m compare.bench.sensing",
        description="Time the depth pipeline's stages per 512×424 frame (render, self-filter, depth-space\n"
        "distance, with one and two cameras) and the geometric source; prints medians and p95 [µs].",
    )
    parser.add_argument("repeats", type=positive_int, nargs="?", default=200, help="timed calls per stage")
    args = parser.parse_args(argv)
    rows = run_sensing_bench(args.repeats)
    info = versions()
    print(f"python {info.get('python')}, mujoco {info.get('mujoco')}, numpy {info.get('numpy')}, cpu {info.get('cpu')}")
    print(format_table(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())

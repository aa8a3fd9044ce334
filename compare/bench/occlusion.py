r"""Occlusion bench: depth-space distance with one and two cameras against the MuJoCo geometry.

Random held-out scenes (arm pose, person pose and hands reaching near the control points, all
from a seed) are rendered by every camera of a rig; each control point's reading is compared
with the truth **from MuJoCo itself**, not from the project's capsule distance:

* true distance and closest person point: ``mujoco.mj_geomDistance`` between a probe sphere at
  the control point and each person geom;
* visibility of that point from each camera: ``mujoco.mj_ray`` from the optical centre (the
  first geom hit: the person point itself = *visible*, else hidden by the arm, the person or
  the static scene);
* self-filter blind zone: ``mj_geomDistance`` from the point to the arm's visual geoms below
  the camera's self-filter margin (+ 5 mm): such a point is removed with the arm by design.

Per control point with the person within ρ the bench counts, for one camera (the scene's
``depth_camera``, today's pipeline) and for the rig (:mod:`compare.sensing.fusion`):

* **false far (visible)**: the truth's closest point is visible to some camera of the setup
  (and outside every seeing camera's self-filter margin) but the reading exceeds the truth by
  more than 1.5 pixel footprints (or says nothing in range);
* **false far (seen by a rig camera)**: the same on the points some camera of the *rig* sees,
  for both setups (what the one-camera setup misses that a second camera would see);
* **false far (hidden)**: the same for points no camera sees (by cause);
* **false near**: the reading is more than ``near_tolerance_m`` below the truth (also for a
  control point with nobody within ρ); **shadow false near**: those whose reading is
  ``occluded``, i.e. assumed from hidden space;
* **visible error**: reading − truth where the closest point is visible (median, p95, max).

The points are also grouped by how the rig's cameras see the closest person point
(``visible``, ``person``: hidden behind the person, ``arm``: behind the arm, ``margin``: in the
self-filter's blind zone, ``contact``: the control point is inside the person, ...), with the
false far count and the largest over-estimate of each setup.

Run (prints Markdown tables, writes JSON)::

    MUJOCO_GL=egl python -m compare.bench.occlusion --scenes 200 --seed 1000 --json occlusion.json

Seeds 0–99 were used while choosing the fusion's defaults (step 1 cm, tolerance 2 mm) and the
second camera's pose; the documented measurement uses seeds from 1000 on.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
import tomllib
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

os.environ.setdefault("MUJOCO_GL", "egl")

import mujoco  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.backends.backend_agg import FigureCanvasAgg  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402

import robots  # noqa: E402
from compare.arguments import (  # noqa: E402
    ArgumentParser,
    existing_file,
    fraction,
    non_negative_float,
    output_path,
    positive_float,
    positive_int,
)
from compare.sensing import (  # noqa: E402
    PERSON_GROUP,
    ROBOT_VISUAL_GROUP,
    STATIC_GROUP,
    DepthPipeline,
    DepthRig,
    DepthSensingSettings,
    Person,
    PersonKeyframe,
    SensingError,
    control_point_positions,
    set_arm_configuration,
    valid_fraction,
)
from compare.sensing.camera import camera_model_from_mujoco, project  # noqa: E402
from compare.sensing.fusion import FusionSettings  # noqa: E402
from compare.sensing.rig import add_cameras  # noqa: E402
from compare.versions import versions  # noqa: E402

DEFAULT_CONFIG = Path(__file__).resolve().parents[2] / "configs" / "case1_two_cameras.toml"
"""The rig measured by default: the cameras of the two-camera case-1 config."""

PROBE = "occlusion_probe"
_PROBE_RADIUS_M = 1e-3
_PROBE_GROUP = 5  # never rendered (cameras draw groups 0-2)


@dataclass(frozen=True)
class CameraSpec:
    """A camera of the measured rig (the fields of ``[[sensor.cameras]]`` the rig needs)."""

    name: str
    position_m: tuple[float, float, float] | None = None
    look_at_m: tuple[float, float, float] | None = None
    quaternion_xyzw: tuple[float, float, float, float] | None = None
    resolution: tuple[int, int] | None = None
    focal_px: tuple[float, float] | None = None
    principal_px: tuple[float, float] | None = None
    range_m: tuple[float, float] | None = None


def cameras_from_config(path: Path) -> list[CameraSpec]:
    """The ``[[sensor.cameras]]`` of a scenario file."""
    data = tomllib.loads(Path(path).read_text(encoding="utf-8"))
    fields = set(CameraSpec.__dataclass_fields__)
    out = []
    for cam in data.get("sensor", {}).get("cameras", []):
        out.append(CameraSpec(**{k: tuple(v) if isinstance(v, list) else v for k, v in cam.items() if k in fields}))
    return out


def bench_model(cameras: Sequence[CameraSpec], robot: str = robots.DEFAULT_ROBOT) -> mujoco.MjModel:
    """The work cell with the rig's cameras and an unrendered probe sphere (a mocap body)."""
    spec = robots.load(robot).workcell_spec()
    add_cameras(spec, cameras)
    body = spec.worldbody.add_body(name=PROBE, mocap=True, pos=[0.0, 0.0, -5.0])
    body.add_geom(
        name=PROBE,
        type=mujoco.mjtGeom.mjGEOM_SPHERE,
        size=[_PROBE_RADIUS_M, 0, 0],
        group=_PROBE_GROUP,
        contype=0,
        conaffinity=0,
    )
    return spec.compile()


@dataclass
class Scene:
    """One random scene: arm configuration and person keyframe."""

    q: np.ndarray
    person: PersonKeyframe


def random_scene(rng: np.random.Generator, robot: robots.Robot) -> Scene:
    """Arm anywhere in its limits with the control points above the table; a person around it.

    The person stands 0.55–1.25 m from the base on any side, facing it within ±0.6 rad; each hand
    reaches (probability 0.85) for a point 5–45 cm from a random control point, else hangs.
    """
    lo = np.where(np.isfinite(robot.q_lower), robot.q_lower + 0.05, -np.pi)
    hi = np.where(np.isfinite(robot.q_upper), robot.q_upper - 0.05, np.pi)
    while True:
        q = rng.uniform(lo, hi)
        kin = robot.kinematics(q)
        points = [kin.frame_position(cp) for cp in robot.control_points]
        if min(p[2] for p in points) > 0.08 and max(np.hypot(p[0], p[1]) for p in points) < 0.8:
            break
    angle = rng.uniform(-math.pi, math.pi)
    radius = rng.uniform(0.55, 1.25)
    pos = (radius * math.cos(angle), radius * math.sin(angle))
    yaw = angle + math.pi + rng.uniform(-0.6, 0.6)
    hands: list[tuple[float, float, float] | None] = []
    for _ in range(2):
        if rng.random() < 0.85:
            target = points[int(rng.integers(len(points)))]
            direction = rng.normal(size=3)
            direction /= np.linalg.norm(direction)
            hands.append(tuple(float(v) for v in target + direction * rng.uniform(0.05, 0.45)))
        else:
            hands.append(None)
    return Scene(q, PersonKeyframe(0.0, pos, yaw, right_hand=hands[0], left_hand=hands[1]))


@dataclass
class PointRecord:
    """One control point of one scene: truth, visibility and the readings."""

    scene: int
    control_point: str
    truth_m: float
    depth_m: float
    visible_to: list[str]
    hidden_by: dict[str, str]
    one_m: float
    one_occluded: bool
    two_m: float
    two_occluded: bool
    two_camera: str | None


@dataclass
class Truth:
    """MuJoCo's answer for one control point."""

    distance_m: float
    closest: np.ndarray
    depth_m: float = math.nan  # largest depth of the closest point in the cameras that see it
    hidden_by: dict[str, str] = field(default_factory=dict)  # camera → visible|arm|person|static|out_of_view|margin


class GroundTruth:
    """Distances, closest points and visibility from MuJoCo's collision and ray functions (module docstring)."""

    def __init__(self, model: mujoco.MjModel, cameras: Sequence[str], margins_m: Sequence[float]) -> None:
        self.model = model
        self.probe = model.geom(PROBE).id
        self.probe_mocap = int(model.body_mocapid[model.body(PROBE).id])
        self.person_geoms = [int(g) for g in np.flatnonzero(model.geom_group == PERSON_GROUP)]
        self.arm_geoms = [int(g) for g in np.flatnonzero(model.geom_group == ROBOT_VISUAL_GROUP)]
        self.cameras = [camera_model_from_mujoco(model, c) for c in cameras]
        self.names = list(cameras)
        self.margins = list(margins_m)
        self._groups = np.zeros(6, dtype=np.uint8)
        self._groups[[STATIC_GROUP, PERSON_GROUP, ROBOT_VISUAL_GROUP]] = 1

    def _probe_at(self, data: mujoco.MjData, point: np.ndarray) -> None:
        data.mocap_pos[self.probe_mocap] = point
        mujoco.mj_kinematics(self.model, data)

    def _distance(self, data: mujoco.MjData, geoms: list[int], distmax: float) -> tuple[float, np.ndarray | None]:
        best, closest = math.inf, None
        fromto = np.zeros(6)
        for g in geoms:
            d = mujoco.mj_geomDistance(self.model, data, self.probe, g, distmax, fromto)
            if d < best:
                best, closest = d, fromto[3:].copy()
        return best + _PROBE_RADIUS_M, closest

    def measure(self, data: mujoco.MjData, point: np.ndarray, distmax: float) -> Truth:
        """Truth for a control point at ``point`` (data after ``mj_kinematics``; the probe is moved)."""
        self._probe_at(data, point)
        dist, closest = self._distance(data, self.person_geoms, distmax)
        if closest is None or not math.isfinite(dist):
            return Truth(math.inf, np.full(3, np.nan))
        truth = Truth(max(dist, 0.0), closest)
        if dist <= 0.0:  # the control point is inside the person: contact, no view question
            truth.hidden_by = dict.fromkeys(self.names, "contact")
            return truth
        self._probe_at(data, closest)
        arm_gap, _ = self._distance(data, self.arm_geoms, 1.0)
        for cam, name, margin in zip(self.cameras, self.names, self.margins, strict=True):
            truth.hidden_by[name] = self._visibility(data, cam, closest, arm_gap, margin)
            if truth.hidden_by[name] == "visible":
                truth.depth_m = max(np.nan_to_num(truth.depth_m), float(project(cam, closest[None, :])[1][0]))
        return truth

    def _visibility(self, data: mujoco.MjData, cam: Any, point: np.ndarray, arm_gap: float, margin: float) -> str:
        """How camera ``cam`` sees ``point`` (the true closest person point).

        Returns:
            ``visible``; ``margin`` (in the self-filter's blind zone: removed with the arm whatever
            the view); ``out_of_view``; or what hides it: ``arm``, ``person``, ``margin_shadow`` (a
            person surface inside the margin) or ``static``.
        """
        if arm_gap < margin + 5e-3:
            return "margin"
        uv, depth = project(cam, point[None, :])
        u, v = uv[0]
        if not (
            cam.min_range_m <= depth[0] <= cam.max_range_m
            and -0.5 <= u < cam.width - 0.5
            and -0.5 <= v < cam.height - 0.5
        ):
            return "out_of_view"
        origin = cam.transform_base_to_camera[:3, 3]
        ray = point - origin
        length = float(np.linalg.norm(ray))
        geom = np.array([-1], dtype=np.int32)
        hit = mujoco.mj_ray(self.model, data, origin, ray / length, self._groups, 1, -1, geom)
        if hit >= 0 and hit < length - 3e-3:
            group = int(self.model.geom_group[int(geom[0])])
            if group == PERSON_GROUP:
                # A person surface within the self-filter margin is removed with the arm: its shadow
                # counts as the arm's (no hidden space of its own), as with one camera.
                self._probe_at(data, origin + ray / length * hit)
                gap, _ = self._distance(data, self.arm_geoms, 1.0)
                self._probe_at(data, point)
                return "margin_shadow" if gap < margin + 5e-3 else "person"
            return "arm" if group == ROBOT_VISUAL_GROUP else "static"
        return "visible"


def run_scenes(
    n_scenes: int,
    seed: int,
    config: Path = DEFAULT_CONFIG,
    rho_m: float = 0.5,
    noise_std_m: float = 0.0,
    dropout: float = 0.0,
    fusion: FusionSettings | None = None,
) -> tuple[list[PointRecord], dict[str, float]]:
    """Render ``n_scenes`` scenes from ``seed`` on; one-camera and rig readings with MuJoCo's truth.

    Returns:
        The records (one per scene and control point), and the cost: CPU time [ms] of the
        distance step (one camera; two cameras fused, searches included; mean and max over the
        scenes), the share of scenes where the fusion searched hidden space and its samples.
    """
    robot = robots.load(robots.DEFAULT_ROBOT)
    cams = cameras_from_config(config)
    if len(cams) < 2:
        raise ValueError(f"{config}: needs two or more [[sensor.cameras]]")
    model = bench_model(cams, robot.name)
    base = DepthSensingSettings(rho_m=rho_m, noise_std_m=noise_std_m, dropout=dropout, seed=seed)
    settings = [
        DepthSensingSettings(**{**asdict(base), "camera": c.name, "seed": seed + 7919 * i}) for i, c in enumerate(cams)
    ]
    rig = DepthRig(model, settings, fusion)
    one: DepthPipeline = rig.pipelines[0]
    truth = GroundTruth(model, [c.name for c in cams], [s.self_filter_margin_m for s in settings])
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, model.keyframe("home").id)
    rng = np.random.default_rng(seed)
    records: list[PointRecord] = []
    cpu_one: list[float] = []
    cpu_two: list[float] = []
    samples: list[int] = []
    try:
        for i in range(n_scenes):
            scene = random_scene(rng, robot)
            set_arm_configuration(model, data, scene.q)
            Person(model, [scene.person]).apply(0.0, data)
            mujoco.mj_forward(model, data)
            points = control_point_positions(robot.kinematics(scene.q), robot.control_points)
            frames = rig.render(data)
            filtered = rig.filter(frames, data=data)
            fractions = [valid_fraction(f) for f in frames]
            if i == 0:  # load the compiled kernels before timing
                one.distance.compute(filtered[0], points, fractions[0])
                rig.fusion.compute(filtered, points, fractions, raw_frames=frames)
            t0 = time.thread_time()
            r1 = one.distance.compute(filtered[0], points, fractions[0])
            t1 = time.thread_time()
            r2 = rig.fusion.compute(filtered, points, fractions, raw_frames=frames)
            t2 = time.thread_time()
            cpu_one.append((t1 - t0) * 1e3)
            cpu_two.append((t2 - t1) * 1e3)
            samples.append(rig.fusion.last_samples)
            for cp, p in points.items():
                tr = truth.measure(data, p, distmax=rho_m + 1.0)
                a, b = r1.readings[cp], r2.readings[cp]
                records.append(
                    PointRecord(
                        scene=i,
                        control_point=cp,
                        truth_m=tr.distance_m,
                        depth_m=tr.depth_m,
                        visible_to=[c for c, h in tr.hidden_by.items() if h == "visible"],
                        hidden_by=tr.hidden_by,
                        one_m=a.distance_m,
                        one_occluded=a.occluded,
                        two_m=b.distance_m,
                        two_occluded=b.occluded,
                        two_camera=b.camera,
                    )
                )
    finally:
        rig.close()
    cost = {
        "distance_cpu_ms_one": _mean_max(cpu_one),
        "distance_cpu_ms_two": _mean_max(cpu_two),
        "scenes_with_search": float(np.count_nonzero(samples)) / max(len(samples), 1),
        "search_samples": _mean_max(samples),
    }
    return records, cost


def _mean_max(values: Sequence[float]) -> dict[str, float]:
    return {"mean": float(np.mean(values)), "max": float(np.max(values))} if len(values) else {"mean": 0.0, "max": 0.0}


def footprint_m(depth_m: float, f_px: float = 365.5) -> float:
    """1.5 pixel footprints at depth ``depth_m`` [m] (the tolerance of a visible reading) plus 1 mm."""
    return 1.5 * depth_m / f_px + 1e-3


def summarize(records: Sequence[PointRecord], rho_m: float = 0.5, near_tolerance_m: float = 0.05) -> dict[str, Any]:
    """Counts and errors for the one-camera setup and the rig (module docstring)."""
    out: dict[str, Any] = {}
    for setup, attr, occ_attr in (("one", "one_m", "one_occluded"), ("two", "two_m", "two_occluded")):
        far_vis = far_hidden = near = shadow_near = far_any = 0
        errors: list[float] = []
        over_hidden: dict[str, list[float]] = {}
        in_range = 0
        for r in records:
            reading = getattr(r, attr)
            occluded = getattr(r, occ_attr)
            # The one-camera setup is judged on what its own camera (the first) sees.
            causes = r.hidden_by if setup == "two" else dict(list(r.hidden_by.items())[:1])
            if r.truth_m <= rho_m - 0.01:
                in_range += 1
                tol = footprint_m(r.depth_m if math.isfinite(r.depth_m) else 2.5)
                if "visible" in r.hidden_by.values() and not reading <= r.truth_m + tol:
                    far_any += 1  # seen by some camera of the rig, whatever this setup has
                if "visible" in causes.values():
                    errors.append(reading - r.truth_m if math.isfinite(reading) else math.inf)
                    if not reading <= r.truth_m + tol:
                        far_vis += 1
                else:
                    cause = "+".join(sorted(set(causes.values())))
                    over_hidden.setdefault(cause, []).append(
                        reading - r.truth_m if math.isfinite(reading) else math.inf
                    )
                    if not reading <= r.truth_m + tol:
                        far_hidden += 1
            if reading < min(r.truth_m, rho_m) - near_tolerance_m:
                near += 1
                shadow_near += bool(occluded)
        e = np.array([x for x in errors if math.isfinite(x)])
        out[setup] = {
            "points_within_rho": in_range,
            "visible_points": len(errors),
            "false_far_visible": far_vis,
            "false_far_seen_by_a_rig_camera": far_any,
            "false_far_hidden": far_hidden,
            "false_near": near,
            "shadow_false_near": shadow_near,
            "visible_error_median_m": float(np.median(np.abs(e))) if e.size else None,
            "visible_error_p95_m": float(np.percentile(np.abs(e), 95)) if e.size else None,
            "visible_error_max_m": float(np.max(e)) if e.size else None,
            "hidden_over_estimate_max_m": {
                k: (float(max(v)) if all(math.isfinite(x) for x in v) else None) for k, v in sorted(over_hidden.items())
            },
            "hidden_points": {k: len(v) for k, v in sorted(over_hidden.items())},
        }
    return out


def by_cause(records: Sequence[PointRecord], rho_m: float = 0.5) -> dict[str, dict[str, Any]]:
    """Per visibility class of the rig (cameras' causes joined by ``+``): points, false far, worst over-estimate."""
    out: dict[str, dict[str, Any]] = {}
    for r in records:
        if r.truth_m > rho_m - 0.01:
            continue
        tol = footprint_m(r.depth_m if math.isfinite(r.depth_m) else 2.5)
        row = out.setdefault(
            "+".join(sorted(set(r.hidden_by.values()))),
            {
                "points": 0,
                "false_far_one": 0,
                "false_far_two": 0,
                "over_max_one_m": -math.inf,
                "over_max_two_m": -math.inf,
            },
        )
        row["points"] += 1
        for setup, reading in (("one", r.one_m), ("two", r.two_m)):
            row[f"false_far_{setup}"] += not reading <= r.truth_m + tol
            row[f"over_max_{setup}_m"] = max(row[f"over_max_{setup}_m"], reading - r.truth_m)
    return dict(sorted(out.items()))


def format_markdown(summary: dict[str, Any], causes: dict[str, dict[str, Any]]) -> str:
    """The summary and the per-class table as Markdown."""
    keys = [
        ("points_within_rho", "control points with the person within ρ", "{}"),
        ("visible_points", "... whose closest person point a camera of the setup sees", "{}"),
        ("false_far_visible", "false far where a camera of the setup sees the person", "{}"),
        ("false_far_seen_by_a_rig_camera", "false far where a camera of the rig sees the person", "{}"),
        ("false_near", "false near (reading > 5 cm below the truth)", "{}"),
        ("shadow_false_near", "... of which assumed from hidden space (occluded)", "{}"),
        ("visible_error_median_m", "visible: median abs. error [mm]", "{:.2f}"),
        ("visible_error_p95_m", "visible: p95 abs. error [mm]", "{:.2f}"),
        ("visible_error_max_m", "visible: largest over-estimate [mm]", "{:+.2f}"),
    ]
    lines = ["| | one camera | two cameras |", "|---|---:|---:|"]
    for key, label, fmt in keys:
        cells = []
        for setup in ("one", "two"):
            v = summary[setup][key]
            cells.append("–" if v is None else fmt.format(1e3 * v if key.endswith("_m") else v))
        lines.append(f"| {label} | {cells[0]} | {cells[1]} |")
    lines += [
        "",
        "| closest person point (per rig camera) | points | false far 1 / 2 cam. "
        "| worst over-estimate 1 / 2 cam. [mm] |",
    ]
    lines.append("|---|---:|---:|---:|")
    for cause, row in causes.items():
        lines.append(
            f"| {cause} | {row['points']} | {row['false_far_one']} / {row['false_far_two']} | "
            f"{1e3 * row['over_max_one_m']:+.1f} / {1e3 * row['over_max_two_m']:+.1f} |"
        )
    return "\n".join(lines)


def plot_records(records: Sequence[PointRecord], path: Path, rho_m: float = 0.5) -> Path:
    """Reading against truth per control point, one camera and two, measured vs assumed (occluded)."""
    fig = Figure(figsize=(10.0, 4.6), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(1, 2, sharex=True, sharey=True)
    truth = np.array([min(r.truth_m, rho_m + 0.05) for r in records])
    for ax, setup, title in ((axes[0], "one", "one camera"), (axes[1], "two", "two cameras, fused")):
        reading = np.array([min(getattr(r, f"{setup}_m"), rho_m + 0.05) for r in records])
        occluded = np.array([getattr(r, f"{setup}_occluded") for r in records])
        near = reading < np.minimum(truth, rho_m) - 0.05
        ax.fill_between([0, rho_m + 0.05], [-0.05, rho_m], [0.05, rho_m + 0.1], color="0.9", label="±5 cm")
        ax.plot([0, rho_m + 0.05], [0, rho_m + 0.05], color="0.5", linewidth=0.8)
        ax.plot(truth[~occluded], reading[~occluded], ".", color="tab:blue", markersize=4, label="measured")
        ax.plot(truth[occluded], reading[occluded], ".", color="tab:purple", markersize=4, label="assumed (occluded)")
        ax.set(title=f"{title}: {int(near.sum())} false near", xlabel="true distance [m] (MuJoCo geometry)")
        ax.set_xlim(0, rho_m + 0.06)
        ax.set_ylim(0, rho_m + 0.06)
        ax.grid(alpha=0.3)
    axes[0].set_ylabel(f"reading [m] (nothing within ρ: plotted at {rho_m + 0.05:g})")
    axes[1].legend(loc="lower right", fontsize=8)
    fig.suptitle(f"{len({r.scene for r in records})} held-out scenes, control points with reading or truth within ρ")
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    return path


def _parser() -> ArgumentParser:
    return ArgumentParser(
        prog="python -m compare.bench.occlusion",
        description=__doc__.split("\n\n")[0]
        + "\n\nPrints Markdown tables of false far and false near readings per setup and cause, and the\n"
        "distance step's CPU time; writes the summary and every reading as JSON with --json.",
    )


def _checked_fusion(parser: ArgumentParser, args: argparse.Namespace) -> FusionSettings:
    """The fusion settings; a rig of fewer than two cameras or a bad value is a usage error."""
    try:
        cams = cameras_from_config(args.config)
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError, TypeError) as exc:
        parser.error(f"--config {args.config}: {exc}")
    if len(cams) < 2:
        parser.error(f"--config {args.config}: needs two or more [[sensor.cameras]], has {len(cams)}")
    try:
        return FusionSettings(
            **{k: v for k, v in (("tolerance_m", args.tolerance), ("step_m", args.step)) if v is not None}
        )
    except SensingError as exc:
        parser.error(str(exc))


def main(argv: list[str] | None = None) -> int:
    """Run the bench (``--help``)."""
    parser = _parser()
    parser.add_argument("--scenes", type=positive_int, default=150, help="random scenes")
    parser.add_argument("--seed", type=int, default=1000, help="seed of the first scene")
    parser.add_argument(
        "--config",
        type=existing_file,
        default=DEFAULT_CONFIG,
        help="scenario TOML whose [[sensor.cameras]] form the rig (default: configs/case1_two_cameras.toml)",
    )
    parser.add_argument("--noise", type=non_negative_float, default=0.0, help="depth noise std [m]")
    parser.add_argument("--dropout", type=fraction, default=0.0, help="share of pixels without a return, in [0, 1]")
    parser.add_argument(
        "--tolerance",
        type=non_negative_float,
        default=None,
        help=f"fusion tolerance [m] (default: {FusionSettings.tolerance_m})",
    )
    parser.add_argument(
        "--step", type=positive_float, default=None, help=f"fusion step [m] (default: {FusionSettings.step_m})"
    )
    parser.add_argument("--json", type=output_path, default=None, help="write the summary and the readings here (JSON)")
    parser.add_argument("--plot", type=output_path, default=None, help="write the reading-vs-truth figure (PNG)")
    args = parser.parse_args(argv)
    fusion = _checked_fusion(parser, args)
    records, cost = run_scenes(
        args.scenes, args.seed, args.config, noise_std_m=args.noise, dropout=args.dropout, fusion=fusion
    )
    summary = summarize(records)
    summary["by_cause"] = causes = by_cause(records)
    summary["cost"] = cost
    info = versions()
    print(
        f"{args.scenes} scenes from seed {args.seed}, {args.config.name}; "
        f"mujoco {info.get('mujoco')}, cpu {info.get('cpu')}"
    )
    print(format_markdown(summary, causes))
    one, two, search = cost["distance_cpu_ms_one"], cost["distance_cpu_ms_two"], cost["search_samples"]
    print(
        f"distance step CPU time: one camera {one['mean']:.2f} ms mean ({one['max']:.2f} max), two cameras "
        f"{two['mean']:.2f} ms ({two['max']:.2f}); fusion searched hidden space in "
        f"{100 * cost['scenes_with_search']:.0f} % of the scenes, {search['mean']:.0f} samples on average, "
        f"at most {search['max']:.0f}"
    )
    if args.plot is not None:
        shown = [r for r in records if min(r.truth_m, r.one_m, r.two_m) <= 0.5]
        print(f"figure: {plot_records(shown, args.plot)}")
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({"summary": summary, "records": [asdict(r) for r in records]}, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())

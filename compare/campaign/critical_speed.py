r"""Critical approach speed: how fast may the person come before a method lets them too close?

``tpik-compare critical-speed CONFIG`` keeps the geometry of a scripted case (the arm's start,
waypoints and hierarchy, the person's path) and re-times the person's motion to a swept speed:
every segment between two keyframes in which the person moves takes
:math:`\max(d_{torso}/v_{torso},\ d_{hand}/v_{hand})` (both hands), a hold keeps its original end
so the next motion starts when it did in the case (unless the slower motion is still going on).
The torso speed :math:`v_{torso}` is swept over 0.1–1.6 m/s (log-spaced, 12 speeds by default)
and the hand speed tied to it over 0.1–2.0 m/s (:func:`hand_speed`: the same fraction of each
range on a log scale; ISO 13855's walking and hand speeds at the top).

Each speed is run in several *directions*: seed 0 is the case's own path; seed k > 0 turns the
person's whole path about the arm's base axis by an angle drawn from ±``spread_deg`` and shifts
every motion in time by up to ±``shift_s`` (a different phase of the arm's own motion), both from
``numpy.random.default_rng(k)``; the same directions at every speed.

Per method, the *critical speed* for a threshold (safety or physical, of the obstacle tasks) is the
highest swept speed at which every run at that speed and at every slower one kept every control
point beyond it (ground truth, the metrics' 1 mm tolerance); ``None`` when even the slowest speed
failed, the top speed when none failed. ``DIR/critical_speed.json`` (docs/design.md §7)::

    {method: {"safety_mps": v, "physical_mps": v, "curve": [[speed_mps, min_distance_m], ...]}}

(the curve: per torso speed, the minimum distance over its runs). ``critical_speed_detail.json``
holds the rest: speeds, hand speeds, directions, every run, the kinematic bound, the oracle's curve
(with ``--oracle``), the command and versions. ``critical_speed.png`` plots it;
``claims_at_critical.json`` holds the paper's claims (:mod:`compare.analysis.claims`) measured on
each method's seed-0 run at its critical speed (at the slowest swept speed when none held).

**Reactive lag.** A velocity-level set-based obstacle task with gain K asks the control point
for :math:`\dot\sigma = K(\sigma_s - \sigma)` (TPIK: the task inserted with the safety threshold as
its target, eq. 7; HQP: the bound :math:`J\dot q \ge -K(\sigma - \sigma_s)`), with no feed-forward of the
person's motion. A person point closing in at speed v then holds σ at :math:`\sigma_s - v/K` once the
task acts: the plot draws :math:`\sigma_s - v_{hand}/K` for comparison.

**Kinematic bound.** At the configuration of the arm when the person starts to approach, the
fastest a control point c can move along the approach direction u within the joint velocity limits
is the linear program :math:`\max_{|\dot q_i| \le v_i} u^T J_c \dot q = \sum_i v_i |u^T J_{c,i}|`.
A person point coming faster than this closes the gap whatever the controller does; the plot marks
the largest such speed per control point over the runs.
"""

from __future__ import annotations

import json
import logging
import math
import shlex
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

import robots
from compare.analysis.avoidability import has_oracle
from compare.analysis.claims import claims_for_run
from compare.analysis.critical_speed_results import (
    CLAIMS_FILE,
    CRITICAL_SPEED_FILE,
    DETAIL_FILE,
    TORSO_RANGE_MPS,
    hand_speed,
)
from compare.analysis.metrics import to_jsonable
from compare.analysis.person_speeds import resolved_hands
from compare.analysis.plots_critical import plot_critical_speed
from compare.analysis.results import is_finished, load_steps, load_summary, run_versions, write_json_atomic
from compare.campaign.executors import Job, LocalExecutor
from compare.config import Config, ConfigError, PersonKeyframe, dump_config
from tpik.tasks import ObstacleDistanceTask

log = logging.getLogger(__name__)

DEFAULT_SPEED_COUNT = 12
MIN_SEGMENT_S = 0.05
"""Shortest re-timed motion segment [s] (keyframe times must increase strictly)."""


class CriticalSpeedError(ConfigError):
    """A bad option of ``critical-speed`` (one line naming it; exit code 2 in the CLI)."""


def default_speeds(n: int = DEFAULT_SPEED_COUNT) -> list[float]:
    """``n`` torso speeds log-spaced over :data:`TORSO_RANGE_MPS` [m/s]."""
    return [float(v) for v in np.geomspace(*TORSO_RANGE_MPS, n)]


@dataclass(frozen=True)
class Direction:
    """One approach direction: seed, turn of the person's path [rad], time shift [s]."""

    seed: int
    angle_rad: float
    shift_s: float


def directions(seeds: int, spread_deg: float, shift_s: float) -> list[Direction]:
    """Seed 0 = the case's own path; seed k > 0 drawn from ``default_rng(k)`` (module docstring)."""
    out = [Direction(0, 0.0, 0.0)]
    for k in range(1, seeds):
        rng = np.random.default_rng(k)
        angle = math.radians(float(rng.uniform(-spread_deg, spread_deg)))
        out.append(Direction(k, angle, float(rng.uniform(-shift_s, shift_s))))
    return out


def _moves(a: PersonKeyframe, b: PersonKeyframe) -> bool:
    return not (
        tuple(a.position) == tuple(b.position)
        and a.yaw == b.yaw
        and a.right_hand == b.right_hand
        and a.left_hand == b.left_hand
    )


def retime_keyframes(
    frames: Sequence[PersonKeyframe],
    hands: Sequence[tuple[np.ndarray, np.ndarray]],
    torso_mps: float,
    hand_mps: float,
    time_scale: float = 1.0,
) -> list[PersonKeyframe]:
    """The person's keyframes with every motion at the given speeds (module docstring).

    Args:
        frames: The case's keyframes (unscaled times).
        hands: Resolved right and left hand positions at each keyframe [m] (a keyframe without a
            target has its hanging hand).
        torso_mps: Torso speed [m/s] (real time, after ``time_scale``).
        hand_mps: Hand speed [m/s].
        time_scale: The scenario's time scale (keyframe times are multiplied by it).

    Returns:
        New keyframes, same poses, new (unscaled) times.
    """
    out = [frames[0]]
    t_new = frames[0].t
    for k in range(len(frames) - 1):
        a, b = frames[k], frames[k + 1]
        if _moves(a, b):
            d_torso = math.dist(a.position, b.position)
            d_hand = max(float(np.linalg.norm(hands[k + 1][s] - hands[k][s])) for s in (0, 1))
            real = max(d_torso / torso_mps, d_hand / hand_mps, MIN_SEGMENT_S)
            t_new += real / time_scale
        else:
            t_new = max(t_new + MIN_SEGMENT_S / time_scale, b.t)  # a hold keeps its original end
        out.append(b.model_copy(update={"t": t_new}))
    return out


def rotate_keyframes(frames: Sequence[PersonKeyframe], angle_rad: float) -> list[PersonKeyframe]:
    """The person's path turned by ``angle_rad`` about the base's z axis."""
    c, s = math.cos(angle_rad), math.sin(angle_rad)

    def turn(v: Sequence[float] | None) -> tuple[float, float, float] | None:
        if v is None:
            return None
        return (c * v[0] - s * v[1], s * v[0] + c * v[1], float(v[2]))

    return [
        f.model_copy(
            update={
                "position": (c * f.position[0] - s * f.position[1], s * f.position[0] + c * f.position[1]),
                "yaw": f.yaw + angle_rad,
                "right_hand": turn(f.right_hand),
                "left_hand": turn(f.left_hand),
            }
        )
        for f in frames
    ]


def shift_keyframes(frames: Sequence[PersonKeyframe], shift_s: float) -> list[PersonKeyframe]:
    """Every keyframe but the first moved by ``shift_s`` [s] (kept after the first)."""
    if len(frames) < 2:
        return list(frames)
    shift = max(shift_s, frames[0].t - frames[1].t + MIN_SEGMENT_S)
    return [frames[0]] + [f.model_copy(update={"t": f.t + shift}) for f in frames[1:]]


def approach_variant(
    config: Config, torso_mps: float, direction: Direction, hands: Sequence[tuple[np.ndarray, np.ndarray]]
) -> Config:
    """The case ``config`` with the person at ``torso_mps`` (hand at :func:`hand_speed`) in ``direction``.

    The duration is extended when the slower motion ends later than the case's (the case's tail
    after the last keyframe is kept).
    """
    frames = list(config.person.keyframes)
    if len(frames) < 2:
        raise CriticalSpeedError("person.keyframes: the case has no person motion to re-time")
    sc = config.scenario
    retimed = retime_keyframes(frames, hands, torso_mps, hand_speed(torso_mps), sc.time_scale)
    moved = shift_keyframes(rotate_keyframes(retimed, direction.angle_rad), direction.shift_s / sc.time_scale)
    tail = max(sc.duration_s - frames[-1].t, 0.0)
    duration = max(sc.duration_s, moved[-1].t + tail)
    name = f"{sc.name}@{torso_mps:.3f}mps-s{direction.seed}"
    return config.model_copy(
        update={
            "scenario": sc.model_copy(update={"duration_s": duration, "name": name}),
            "person": config.person.model_copy(update={"keyframes": moved}),
        }
    )


def approach_direction(frames: Sequence[PersonKeyframe]) -> tuple[float, np.ndarray] | None:
    """Start time of the first motion (unscaled) [s] and its direction (unit, base frame).

    The torso's displacement over the first motion segment (horizontal), or the right hand's when
    the torso does not move; None when the person never moves.
    """
    for k in range(len(frames) - 1):
        if not _moves(frames[k], frames[k + 1]):
            continue
        a, b = frames[k], frames[k + 1]
        d = np.array([*np.subtract(b.position, a.position), 0.0])
        if np.linalg.norm(d) < 1e-6 and a.right_hand is not None and b.right_hand is not None:
            d = np.subtract(b.right_hand, a.right_hand)
        n = float(np.linalg.norm(d))
        return (frames[k].t, d / n) if n > 1e-9 else None
    return None


def retreat_speed_bound(kin: robots.Kinematics, frame: str, direction: np.ndarray, v_max: np.ndarray) -> float:
    r"""Fastest speed of ``frame``'s origin along ``direction`` within the joint velocity limits [m/s].

    .. math:: \max_{|\dot q_i| \le v_i} u^T J \dot q = \sum_i v_i\,|u^T J_{:,i}|
    """
    u = np.asarray(direction, dtype=float)
    u = u / np.linalg.norm(u)
    return float(np.abs(u @ kin.position_jacobian(frame)) @ v_max)


# ---------------------------------------------------------------------------------------- running


def _run_name(speed: float, seed: int) -> str:
    return f"v{speed:.3f}-s{seed}"


@dataclass(frozen=True)
class _Run:
    speed: float
    direction: Direction
    config: Config
    run_dir: Path


def _plan(
    config: Config, out_dir: Path, speeds: Sequence[float], dirs: Sequence[Direction], robot: robots.Robot
) -> list[_Run]:
    hands = resolved_hands(config, robot)
    runs = []
    for v in speeds:
        for d in dirs:
            variant = approach_variant(config, v, d, hands)
            checked = Config.model_validate(variant.model_dump(mode="python"))  # keyframe order, duration
            runs.append(_Run(v, d, checked, out_dir / "runs" / _run_name(v, d.seed)))
    return runs


def _finished(run: _Run) -> bool:
    return is_finished(run.run_dir, run.config.methods.names) and (
        not run.config.oracle.enabled or has_oracle(run.run_dir)
    )


def critical(curve_ok: Sequence[tuple[float, bool]]) -> float | None:
    """Highest speed such that it and every slower speed held; None if the slowest failed."""
    best = None
    for speed, ok in sorted(curve_ok):
        if not ok:
            break
        best = speed
    return best


def _method_rows(run: _Run, summary: dict[str, Any]) -> dict[str, dict[str, Any]]:
    rows = {}
    for name, m in (summary.get("methods") or {}).items():
        dists = [d for d in m.get("min_obstacle_distance_m") or [] if d is not None]
        obstacles = m.get("obstacles") or {}
        rows[name] = {
            "min_distance_m": min(dists) if dists else None,
            "held_safety": not obstacles.get("violations"),
            "held_physical": not obstacles.get("physical_violations"),
        }
    return rows


def _bounds(run: _Run, methods: Sequence[str], robot: robots.Robot) -> dict[str, float]:
    """Kinematic bound per control point at the approach start, max over the methods' arms."""
    found = approach_direction(run.config.person.keyframes)
    if found is None:
        return {}
    t_move, u = found
    t_move *= run.config.scenario.time_scale
    tasks = run.config.build_hierarchy(robot).set_tasks
    cps = [t.frame for t in tasks if isinstance(t, ObstacleDistanceTask)]
    out: dict[str, float] = {}
    for name in methods:
        try:
            steps = load_steps(run.run_dir, name)
        except FileNotFoundError:
            continue
        k = int(np.argmin(np.abs(steps["t"].to_numpy(dtype=float) - t_move)))
        q = steps[[f"q_{j + 1}" for j in range(robot.nq)]].to_numpy(dtype=float)[k]
        kin = robot.kinematics(q)
        for cp in cps:
            out[cp] = max(out.get(cp, 0.0), retreat_speed_bound(kin, cp, u, robot.v_max))
    return out


def run_critical_speed(
    config: Config,
    out_dir: Path,
    speeds: Sequence[float] | None = None,
    seeds: int = 3,
    spread_deg: float = 20.0,
    shift_s: float = 2.0,
    workers: int = 1,
    progress: bool = True,
    command: str | None = None,
) -> dict[str, Any]:
    """Run the speed sweep of a case config and write the files of the module docstring.

    Args:
        config: A scripted case (``case1`` / ``case2``) with its methods (and ``[oracle]``).
        out_dir: Output directory (``runs/v<speed>-s<seed>/`` inside; finished runs are skipped).
        speeds: Torso speeds [m/s]; default :func:`default_speeds`.
        seeds: Directions per speed (seed 0 = the case's own).
        spread_deg: Largest turn of the person's path [deg].
        shift_s: Largest time shift of the person's motion [s].
        workers: Worker processes.
        progress: Show a progress bar.
        command: Command line for the detail file (default ``sys.argv``).

    Returns:
        The content of ``critical_speed.json``.

    Raises:
        CriticalSpeedError: Not a scripted case, no person motion, or a bad speed / seed count.
    """
    if config.scenario.kind not in ("case1", "case2"):
        raise CriticalSpeedError(f"scenario.kind: critical-speed needs a scripted case, got '{config.scenario.kind}'")
    speeds = sorted(set(default_speeds() if speeds is None else [float(v) for v in speeds]))
    if not speeds or any(not (0.0 < v <= 10.0) for v in speeds):
        raise CriticalSpeedError(f"--speeds: speeds must be in (0, 10] m/s, got {speeds}")
    if seeds < 1:
        raise CriticalSpeedError(f"--seeds: must be >= 1, got {seeds}")
    robot = config.load_robot()
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    dirs = directions(seeds, spread_deg, shift_s)
    plan = _plan(config, out_dir, speeds, dirs, robot)
    todo = [r for r in plan if not _finished(r)]
    start = time.perf_counter()
    failures: list[str] = []
    columns = (TextColumn("[bold]critical-speed"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn())
    with Progress(*columns, disable=not progress) as bar:
        task = bar.add_task("runs", total=len(plan), completed=len(plan) - len(todo))

        def done(run_dir: Path, error: str | None) -> None:
            if error:
                failures.append(f"{run_dir.name}: {error}")
                log.warning("run %s failed: %s", run_dir.name, error)
            bar.advance(task)

        LocalExecutor(workers).run([Job(r.config, dump_config(r.config), r.run_dir) for r in todo], done)
    wall = time.perf_counter() - start
    return _write_results(config, out_dir, plan, speeds, dirs, robot, failures, wall, len(todo), command)


def _write_results(
    config: Config,
    out_dir: Path,
    plan: Sequence[_Run],
    speeds: Sequence[float],
    dirs: Sequence[Direction],
    robot: robots.Robot,
    failures: list[str],
    wall_s: float,
    executed: int,
    command: str | None,
) -> dict[str, Any]:
    methods = list(config.methods.names)
    runs: list[dict[str, Any]] = []
    bounds: dict[str, float] = {}
    for run in plan:
        try:
            summary = load_summary(run.run_dir)
        except (OSError, ValueError):
            continue
        rows = _method_rows(run, summary)
        for cp, v in _bounds(run, methods, robot).items():
            bounds[cp] = max(bounds.get(cp, 0.0), v)
        runs.append(
            {
                "speed_mps": run.speed,
                "hand_speed_mps": hand_speed(run.speed),
                "seed": run.direction.seed,
                "run": run.run_dir.relative_to(out_dir).as_posix(),
                "methods": rows,
                "oracle": summary.get("oracle"),
            }
        )
    result: dict[str, Any] = {}
    for name in methods:
        per_speed: dict[float, list[dict[str, Any]]] = {}
        for r in runs:
            if name in r["methods"]:
                per_speed.setdefault(r["speed_mps"], []).append(r["methods"][name])
        curve = []
        safety, physical = [], []
        for v in sorted(per_speed):
            rows = per_speed[v]
            dists = [row["min_distance_m"] for row in rows if row["min_distance_m"] is not None]
            curve.append([v, min(dists) if dists else None])
            complete = len(rows) == len(dirs)
            safety.append((v, complete and all(row["held_safety"] for row in rows)))
            physical.append((v, complete and all(row["held_physical"] for row in rows)))
        result[name] = {"safety_mps": critical(safety), "physical_mps": critical(physical), "curve": curve}
    oracle_curve = _oracle_curve(runs, len(dirs))
    write_json_atomic(out_dir / CRITICAL_SPEED_FILE, to_jsonable(result))
    previous: dict[str, Any] = {}
    if (out_dir / DETAIL_FILE).is_file():  # a resumed or re-aggregated sweep adds to what was run
        try:
            previous = json.loads((out_dir / DETAIL_FILE).read_text(encoding="utf-8"))
        except ValueError:
            previous = {}
    this_command = command or " ".join(shlex.quote(a) for a in sys.argv)
    detail = {
        "scenario": config.scenario.name,
        "kind": config.scenario.kind,
        "speeds_mps": list(speeds),
        "hand_speeds_mps": [hand_speed(v) for v in speeds],
        "directions": [{"seed": d.seed, "angle_deg": math.degrees(d.angle_rad), "shift_s": d.shift_s} for d in dirs],
        "sensing": config.scenario.sensing,
        "kinematic_bound_mps": bounds,
        "obstacle_gain_per_s": _obstacle_gain(config, robot),
        "oracle": oracle_curve,
        "runs": runs,
        "failed_runs": failures,
        "wall_time_s": wall_s + float(previous.get("wall_time_s") or 0.0),
        "runs_executed": executed + int(previous.get("runs_executed") or 0),
        "command": previous.get("command", this_command) if executed == 0 else this_command,
        "versions": run_versions(),
    }
    write_json_atomic(out_dir / DETAIL_FILE, to_jsonable(detail))
    _write_claims(out_dir, result, plan)
    try:
        plot_critical_speed(out_dir)
    except Exception as exc:  # plots must never lose the results
        log.warning("critical-speed plot failed: %s", exc)
    return result


def _obstacle_gain(config: Config, robot: robots.Robot) -> float | None:
    """Gain K of the obstacle tasks [1/s] (the smallest, when they differ)."""
    gains = [t.gain for t in config.build_hierarchy(robot).set_tasks if isinstance(t, ObstacleDistanceTask)]
    return min(gains) if gains else None


def _oracle_curve(runs: Sequence[dict[str, Any]], n_dirs: int) -> dict[str, Any] | None:
    per_speed: dict[float, list[dict[str, Any]]] = {}
    for r in runs:
        if isinstance(r.get("oracle"), dict):
            per_speed.setdefault(r["speed_mps"], []).append(r["oracle"])
    if not per_speed:
        return None
    curve = []
    held = []
    for v in sorted(per_speed):
        entries = per_speed[v]
        dists = [e["min_distance_m"] for e in entries if e.get("min_distance_m") is not None]
        curve.append([v, min(dists) if dists else None])
        held.append((v, len(entries) == n_dirs and all(e.get("held_safety") for e in entries)))
    return {"safety_mps": critical(held), "curve": curve}


def _write_claims(out_dir: Path, result: dict[str, Any], plan: Sequence[_Run]) -> None:
    """The paper's claims on each method's seed-0 run at its critical (safety) speed.

    When no swept speed held (critical speed ``None``) the claims are measured at the slowest
    swept speed instead, with ``"critical": false``.
    """
    out: dict[str, Any] = {}
    slowest = min((r.speed for r in plan), default=None)
    for name, entry in result.items():
        v = entry["safety_mps"] if entry["safety_mps"] is not None else slowest
        run = next((r for r in plan if r.direction.seed == 0 and v is not None and math.isclose(r.speed, v)), None)
        if run is None or not (run.run_dir / "summary.json").is_file():
            out[name] = {"speed_mps": v, "critical": entry["safety_mps"] is not None, "run": None, "claims": []}
            continue
        claims = claims_for_run(run.run_dir, [name]).get(name, [])
        out[name] = {
            "speed_mps": v,
            "hand_speed_mps": hand_speed(v),
            "critical": entry["safety_mps"] is not None,
            "run": run.run_dir.relative_to(out_dir).as_posix(),
            "claims": [c.to_dict() for c in claims],
        }
    write_json_atomic(out_dir / CLAIMS_FILE, to_jsonable(out))

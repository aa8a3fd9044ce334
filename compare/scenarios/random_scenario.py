r"""Randomized scenarios drawn from a seed (docs/design.md §5, "beyond the paper").

:func:`realize` turns a config of kind ``random`` into a concrete one: start pose, waypoints,
person path and speed, sensor noise and dropout all come from ``numpy.random.default_rng(seed)``,
so (config, seed) reproduces a run exactly. Scripted kinds (``case1``, ``case2``) pass through.

The ranges are in ``[random]`` (:class:`compare.config.RandomConfig`); the defaults make the
*hard* family of the reliability campaigns:

* **start pose**: the ``home`` pose perturbed by ``start_perturbation_rad``; each joint of a
  joint-limit task is, with ``start_near_limit_probability``, put ``start_limit_offset_rad``
  inside one of its safety thresholds. A pose is kept only if every set task starts inside its
  safety thresholds (the EE inside the walls, no person near) — otherwise it is drawn again, up to
  ``start_pose_attempts`` times, then the plain perturbed pose (clipped 0.2 rad inside the
  physical limits) is used;
* **waypoints**: uniform in the workspace box; each, with ``waypoint_near_wall_probability``, has
  one coordinate moved to a wall of the EE's ``wall_box`` at a signed offset drawn from
  ``waypoint_wall_offset_m`` (positive = beyond the wall, at most 3/4 of the waypoint tolerance
  so it is reached with the EE held on the wall), then clipped to the workspace box (the hard
  family's box reaches 1 cm past the walls);
* **person**: ``person_visits`` visits, one starting in each equal time slot (or as soon as the
  person has walked around the arm, at the away radius, from the previous visit's side; a visit
  may run past the end of the run). Each visit comes from a uniformly drawn side and is one
  motion at a time: the person walks from 1.6 m to ``near_radius_m`` of the base axis with the
  arms hanging, at a walking speed drawn from ``person_speed_mps`` (ISO 13855 / ISO/TS 15066:
  1.6 m/s), raises the hand to 0.25 m short of its target, moves it through the target and
  ``push_depth_m`` beyond (away from the person) at a hand speed drawn from ``hand_speed_mps``
  (up to 2.0 m/s), holds, withdraws and lowers the hand at the same speed, and walks away. The
  target is drawn from ``reach_targets``: near a waypoint, a control point at the start pose
  (``control_points`` stands for every control point of the obstacle tasks, in order: for the
  Jaco² ``link_4``, ``link_6``, ``link_7``), or the EE (``push_ee``: pushing it toward the far
  wall). :func:`retime` then stretches each motion so that no point of the person's capsules
  (elbows and hands of a turning torso included) moves faster than that motion's drawn speed:
  the realized person never exceeds the family's stated speeds.
"""

from __future__ import annotations

import math
from typing import Any

import mujoco
import numpy as np

import robots
from compare.config import Config, PersonKeyframe, RandomConfig
from compare.loop.closed_loop import control_points
from compare.sensing.person import Person
from tpik.tasks import JointLimitTask, ObstacleDistanceTask, SetTask, VirtualWallTask

# Where the person stands when not visiting: this far from the base [m].
_AWAY_RADIUS_M = 1.6
# How far short of its target the hand is when the torso arrives [m].
_APPROACH_M = 0.25
# Hand targets are kept within these heights [m] (table top to above the head of the arm).
_HAND_Z_M = (0.15, 1.3)
# The hand's approach point is at least this far in front of the person's shoulders [m].
_FRONT_M = 0.3
# Nominal path of the hand from hanging to the approach point [m] (retimed by its true length).
_RAISE_M = 0.6
# Retiming: at least this many chords per keyframe segment, each at most this long [s], and
# this relative margin below the speed limit.
_RETIME_SAMPLES = 64
_RETIME_STEP_S = 0.005
_RETIME_MARGIN = 0.01


def realize(config: Config, robot: robots.Robot | None = None, draw: int = 0) -> Config:
    """Return a concrete scenario for ``config.scenario.seed`` (identity for scripted kinds).

    Args:
        config: The scenario family.
        robot: The arm (default the Jaco²).
        draw: Which draw of this seed: 0 is the seed's own, k > 0 an independent redraw
            (``numpy.random.default_rng([seed, k])``; the avoidable family redraws).
    """
    if config.scenario.kind != "random":
        return config
    robot = robot or config.load_robot()
    seed = config.scenario.seed
    rng = np.random.default_rng(seed if draw == 0 else [seed, draw])
    rc = config.random
    hierarchy = config.build_hierarchy(robot)
    set_tasks = hierarchy.set_tasks
    cps = control_points(hierarchy, robot)

    start_q = _start_pose(rng, robot, rc, set_tasks, cps)
    waypoints = _waypoints(rng, rc, set_tasks, config.waypoints.tolerance_m, robot.ee_frame)
    kin = robot.kinematics(start_q)
    reach = reach_target_kinds(rc.reach_targets, cps)
    targets = {kind: kin.frame_position(kind) for kind in reach if kind not in ("waypoint", "push_ee")}
    targets["push_ee"] = kin.frame_position(robot.ee_frame)
    duration = config.scenario.duration_s
    keyframes = retime(*_person_path(rng, duration, rc, waypoints, targets, reach), robot.workcell_model())

    sensor = config.sensor.model_copy(
        update={"noise_std_m": float(rng.uniform(*rc.noise_std_m)), "dropout": float(rng.uniform(*rc.dropout))}
    )
    scenario = config.scenario.model_copy(update={"start_q": tuple(float(v) for v in start_q)})
    waypoint_cfg = config.waypoints.model_copy(update={"positions": waypoints})
    person = config.person.model_copy(update={"keyframes": keyframes})
    return config.model_copy(
        update={"scenario": scenario, "waypoints": waypoint_cfg, "person": person, "sensor": sensor}
    )


def reach_target_kinds(reach_targets: list[str], cps: tuple[str, ...]) -> list[str]:
    """``[random] reach_targets`` with ``control_points`` expanded to the control point frames."""
    out: list[str] = []
    for kind in reach_targets:
        out.extend(cps if kind == "control_points" else [kind])
    return out


def _start_pose(
    rng: np.random.Generator,
    robot: robots.Robot,
    rc: RandomConfig,
    set_tasks: tuple[SetTask, ...],
    cps: tuple[str, ...],
) -> np.ndarray:
    """A start pose inside every set task's safety thresholds, some joints near their limits."""
    lo = np.where(np.isfinite(robot.q_lower), robot.q_lower + 0.2, -np.inf)
    hi = np.where(np.isfinite(robot.q_upper), robot.q_upper - 0.2, np.inf)
    plain = np.clip(robot.home + rng.uniform(-1, 1, robot.nq) * rc.start_perturbation_rad, lo, hi)
    limits = [t for t in set_tasks if isinstance(t, JointLimitTask)]
    checked = [t for t in set_tasks if not isinstance(t, ObstacleDistanceTask)]
    for _ in range(rc.start_pose_attempts):
        q = np.clip(robot.home + rng.uniform(-1, 1, robot.nq) * rc.start_perturbation_rad, lo, hi)
        for task in limits:
            if rng.uniform() < rc.start_near_limit_probability:
                th = task.thresholds
                inset = float(rng.uniform(*rc.start_limit_offset_rad))
                q[task.joint - 1] = th.safety_lower + inset if rng.uniform() < 0.5 else th.safety_upper - inset
        if _inside_safety(robot, q, checked, cps):
            return q
    return plain


def _inside_safety(robot: robots.Robot, q: np.ndarray, tasks: list[SetTask], cps: tuple[str, ...]) -> bool:
    kin = robot.kinematics(q)
    for task in tasks:
        sigma = task.compute_value_and_jacobian(kin)[0]
        th = task.thresholds
        if not th.safety_lower <= sigma <= th.safety_upper:
            return False
    return all(kin.frame_position(f)[2] > 0.05 for f in (*cps, robot.ee_frame))


def _wall_box(set_tasks: tuple[SetTask, ...], ee_frame: str) -> tuple[np.ndarray, np.ndarray] | None:
    """Lower and upper wall positions (x, y, z) of axis-aligned EE walls; None if there are none."""
    lower = np.full(3, np.nan)
    upper = np.full(3, np.nan)
    for task in set_tasks:
        if not isinstance(task, VirtualWallTask) or task.frame != ee_frame:
            continue
        axis = int(np.argmax(np.abs(task.normal)))
        if abs(abs(task.normal[axis]) - 1.0) > 1e-9:
            continue
        # σ = n·p − d ≥ safety_lower: the wall (safety threshold) sits at n·p = d + safety_lower.
        if task.normal[axis] > 0:
            lower[axis] = task.offset + task.thresholds.safety_lower
        else:
            upper[axis] = -(task.offset + task.thresholds.safety_lower)
    if np.all(np.isnan(lower)) and np.all(np.isnan(upper)):
        return None
    return lower, upper


def _waypoints(
    rng: np.random.Generator, rc: RandomConfig, set_tasks: tuple[SetTask, ...], tolerance_m: float, ee_frame: str
) -> list[tuple[float, float, float]]:
    wl, wu = np.array(rc.workspace_lower), np.array(rc.workspace_upper)
    walls = _wall_box(set_tasks, ee_frame)
    out = []
    for _ in range(rc.waypoints):
        p = rng.uniform(wl, wu)
        if walls is not None and rng.uniform() < rc.waypoint_near_wall_probability:
            axis = int(rng.integers(3))
            side = int(rng.integers(2))
            wall = (walls[0] if side == 0 else walls[1])[axis]
            if math.isfinite(wall):
                offset = min(float(rng.uniform(*rc.waypoint_wall_offset_m)), 0.75 * tolerance_m)
                p[axis] = wall - offset if side == 0 else wall + offset
        p = np.clip(p, wl, wu)  # waypoints always stay in the workspace box
        out.append(_vec(p))
    return out


def _person_path(
    rng: np.random.Generator,
    duration_s: float,
    rc: RandomConfig,
    waypoints: list[tuple[float, float, float]],
    targets: dict[str, np.ndarray],
    reach: list[str],
) -> tuple[list[PersonKeyframe], list[float]]:
    """Keyframes of ``rc.person_visits`` visits (module docstring), at their nominal times.

    Returns:
        The keyframes, and the speed limit [m/s] of the motion that ends at each keyframe (the
        visit's walking speed or hand speed; the first entry is unused).
    """
    first_side = rng.uniform(-math.pi, math.pi)
    frames = [_standing(0.0, first_side)]
    limits = [math.inf]
    if rc.person_visits == 0:
        return frames, limits
    slot = duration_s / rc.person_visits
    free_at = 0.0  # end of the previous visit [s]
    last_side = first_side
    for k in range(rc.person_visits):
        walk_speed = float(rng.uniform(*rc.person_speed_mps))
        hand_speed = float(rng.uniform(*rc.hand_speed_mps))
        side = float(rng.uniform(-math.pi, math.pi))
        near = float(rng.uniform(*rc.near_radius_m))
        kind = reach[int(rng.integers(len(reach)))]
        push = float(rng.uniform(*rc.push_depth_m))
        planned = k * slot + float(rng.uniform(0.05, 0.3)) * slot
        hold = float(rng.uniform(0.1, 0.3)) * slot
        noise = rng.normal(0.0, 0.05, 3)
        if k == 0:
            last_side = side  # stand where the first visit starts
            frames = [_standing(0.0, side)]
        # Walk around the arm at the away radius to the new side (never through the work cell).
        turn = math.remainder(side - last_side, math.tau)
        arc_s = _AWAY_RADIUS_M * abs(turn) / walk_speed
        start = max(planned, free_at + arc_s + 0.1)
        if start >= duration_s:  # visits may run past the end, but must start within the run
            break
        if abs(turn) > 1e-6 and k > 0:
            pieces = max(1, math.ceil(abs(turn) / (math.pi / 6)))
            t_arc0 = start - arc_s
            for j in range(1, pieces + 1):
                a = last_side + turn * j / pieces
                frames.append(_standing(t_arc0 + arc_s * j / pieces, a))
                limits.append(walk_speed)
        target = _reach_target(kind, waypoints, targets, rng) + noise
        direction = np.array([math.cos(side), math.sin(side)])
        yaw = side + math.pi  # facing the arm
        # The hand moves through the target away from the person (toward the far wall).
        inward = np.array([-direction[0], -direction[1], 0.0])
        approach = _clip_hand(target - _APPROACH_M * inward)
        end = _vec(_clip_hand(target + push * inward))
        # The hand stays in front of the shoulders: a person reaching for a point at their own
        # shoulder steps back instead (the two-link arm would fold through itself there).
        ahead = float((approach[:2] - near * direction) @ inward[:2])
        near = min(near + max(0.0, _FRONT_M - ahead), _AWAY_RADIUS_M - 0.1)
        away_xy = _xy(_AWAY_RADIUS_M * direction)
        near_xy = _xy(near * direction)
        approach = _vec(approach)
        walk_s = (_AWAY_RADIUS_M - near) / walk_speed
        reach_s = max(math.dist(end, approach) / hand_speed, 0.05)
        raise_s = _RAISE_M / hand_speed
        # Walk in with the arms hanging, raise the hand, reach through the target, hold, withdraw,
        # lower the hand, walk away: one motion at a time, each at its own speed.
        phases = [
            (start, away_xy, None, walk_speed),
            (start + walk_s, near_xy, None, walk_speed),
            (start + walk_s + raise_s, near_xy, approach, hand_speed),
            (start + walk_s + raise_s + reach_s, near_xy, end, hand_speed),
            (start + walk_s + raise_s + reach_s + hold, near_xy, end, hand_speed),
            (start + walk_s + raise_s + 2 * reach_s + hold, near_xy, approach, hand_speed),
            (start + walk_s + 2 * (raise_s + reach_s) + hold, near_xy, None, hand_speed),
            (start + 2 * (walk_s + raise_s + reach_s) + hold, away_xy, None, walk_speed),
        ]
        for t, xy, hand, limit in phases:
            frames.append(PersonKeyframe(t=t, position=xy, yaw=yaw, right_hand=hand))
            limits.append(limit)
        free_at, last_side = phases[-1][0], side
    return _strictly_increasing(frames, limits)


def retime(frames: list[PersonKeyframe], limits: list[float], model: mujoco.MjModel) -> list[PersonKeyframe]:
    r"""Stretch the keyframe segments so that no capsule end of the person moves faster than its limit.

    The pose along a segment depends only on the interpolation weight α ∈ [0, 1], so the
    speed of every capsule end is :math:`|\partial p/\partial\alpha| / T` for a segment of
    duration T. :math:`\max|\partial p/\partial\alpha|` (the arm's own swing included: the
    elbow of the two-link arm, the hands of a turning torso) is measured on chords of at most
    :data:`_RETIME_STEP_S` of the nominal duration, and T becomes
    :math:`\max(T, (1 + \epsilon)\max|\partial p/\partial\alpha| / v)` with the segment's limit v
    and :data:`_RETIME_MARGIN` ε. Later keyframes shift by the added time.

    Args:
        frames: Keyframes at their nominal times.
        limits: Speed limit [m/s] of the segment ending at each keyframe (the first is unused).
        model: A scene with the person (its segment lengths and radii).
    """
    if len(frames) < 2:
        return list(frames)
    person = Person(model, frames)
    times = np.array([f.t for f in frames])
    durations = np.diff(times)
    keys = person.keys_at(times)
    moving = np.flatnonzero(np.any(keys[1:] != keys[:-1], axis=1))  # the pose changes along these segments
    counts = np.maximum(_RETIME_SAMPLES, np.ceil(durations[moving] / _RETIME_STEP_S)).astype(int)
    samples = [times[k] + np.linspace(0.0, 1.0, n + 1) * durations[k] for k, n in zip(moving, counts, strict=True)]
    caps = person.capsule_ends(np.concatenate(samples) if samples else np.zeros(0))
    ends = np.concatenate([caps.a, caps.b], axis=1)  # (S, 2G, 3)
    first = np.concatenate([[0], np.cumsum(counts + 1)])
    stretched = durations.copy()
    for j, (k, n) in enumerate(zip(moving, counts, strict=True)):
        seg = ends[first[j] : first[j + 1]]
        chord = float(np.linalg.norm(np.diff(seg, axis=0), axis=2).max()) * n  # m per unit α
        stretched[k] = max(durations[k], (1.0 + _RETIME_MARGIN) * chord / limits[k + 1])
    new_times = times[0] + np.concatenate([[0.0], np.cumsum(stretched)])
    return [f.model_copy(update={"t": float(t)}) for f, t in zip(frames, new_times, strict=True)]


def _reach_target(
    kind: str, waypoints: list[tuple[float, float, float]], targets: dict[str, np.ndarray], rng: np.random.Generator
) -> np.ndarray:
    if kind == "waypoint":
        return np.array(waypoints[int(rng.integers(len(waypoints)))], dtype=float)
    return np.array(targets[kind], dtype=float)  # "push_ee" is the EE's position


def _clip_hand(p: np.ndarray) -> np.ndarray:
    out = np.array(p, dtype=float)
    out[2] = float(np.clip(out[2], *_HAND_Z_M))
    return out


def _xy(v: np.ndarray) -> tuple[float, float]:
    return (float(v[0]), float(v[1]))


def _vec(v: np.ndarray) -> tuple[float, float, float]:
    return (float(v[0]), float(v[1]), float(v[2]))


def _standing(t: float, side: float) -> PersonKeyframe:
    xy = _AWAY_RADIUS_M * np.array([math.cos(side), math.sin(side)])
    return PersonKeyframe(t=t, position=(float(xy[0]), float(xy[1])), yaw=side + math.pi)


def _strictly_increasing(frames: list[PersonKeyframe], limits: list[float]) -> tuple[list[PersonKeyframe], list[float]]:
    """The keyframes (and their limits) without those less than 1 µs after the previous one."""
    out, out_limits = [frames[0]], [limits[0]]
    for f, limit in zip(frames[1:], limits[1:], strict=True):
        if f.t > out[-1].t + 1e-6:
            out.append(f)
            out_limits.append(limit)
    return out, out_limits


def describe(config: Config) -> dict[str, Any]:
    """A few numbers of a realized random scenario (for reports and tests)."""
    frames = config.person.keyframes
    speeds = []
    for a, b in zip(frames, frames[1:], strict=False):
        dt = b.t - a.t
        if dt > 0:
            speeds.append(math.dist(a.position, b.position) / dt)
    return {
        "start_q": list(config.scenario.start_q or ()),
        "waypoints": [list(p) for p in config.waypoints.positions],
        "keyframes": len(frames),
        "max_walking_speed_mps": max(speeds) if speeds else 0.0,
    }

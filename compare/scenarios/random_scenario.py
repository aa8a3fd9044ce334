"""Randomized scenarios drawn from a seed (DESIGN §5, "beyond the paper").

:func:`realize` turns a config of kind ``random`` into a concrete one: start pose, waypoints,
person path and speed, sensor noise and dropout all come from ``numpy.random.default_rng(seed)``,
so (config, seed) reproduces a run exactly. Scripted kinds (``case1``, ``case2``) pass through.
"""

from __future__ import annotations

import math

import numpy as np

import robots
from compare.config import Config, PersonKeyframe

# Where the person stands when not visiting: this far from the base [m].
_AWAY_RADIUS_M = 1.6
# Closest approach of the torso axis to the base [m] (the table edge is at 0.6 m).
_NEAR_RADIUS_M = (0.75, 0.95)


def realize(config: Config, robot: robots.Robot | None = None) -> Config:
    """Return a concrete scenario for ``config.scenario.seed`` (identity for scripted kinds)."""
    if config.scenario.kind != "random":
        return config
    robot = robot or robots.load("jaco2")
    rng = np.random.default_rng(config.scenario.seed)
    rc = config.random

    lo = np.where(np.isfinite(robot.q_lower), robot.q_lower + 0.2, -np.inf)
    hi = np.where(np.isfinite(robot.q_upper), robot.q_upper - 0.2, np.inf)
    start_q = np.clip(robot.home + rng.uniform(-1, 1, robot.nq) * rc.start_perturbation_rad, lo, hi)

    wl, wu = np.array(rc.workspace_lower), np.array(rc.workspace_upper)
    waypoints = [tuple(float(v) for v in rng.uniform(wl, wu)) for _ in range(rc.waypoints)]

    duration = config.scenario.duration_s
    keyframes = _person_path(rng, duration, rc.person_visits, rc.person_speed_mps, waypoints)

    sensor = config.sensor.model_copy(
        update={"noise_std_m": float(rng.uniform(*rc.noise_std_m)), "dropout": float(rng.uniform(*rc.dropout))}
    )
    scenario = config.scenario.model_copy(update={"start_q": tuple(float(v) for v in start_q)})
    waypoint_cfg = config.waypoints.model_copy(update={"positions": waypoints})
    person = config.person.model_copy(update={"keyframes": keyframes})
    return config.model_copy(
        update={"scenario": scenario, "waypoints": waypoint_cfg, "person": person, "sensor": sensor}
    )


def _person_path(
    rng: np.random.Generator,
    duration_s: float,
    visits: int,
    speed_range: tuple[float, float],
    waypoints: list[tuple[float, float, float]],
) -> list[PersonKeyframe]:
    """Keyframes: stand away, walk in from a random side at a random speed, reach, walk out."""
    side = rng.uniform(-math.pi, math.pi)
    frames = [_standing(0.0, side)]
    if visits == 0:
        return frames
    slot = duration_s / visits
    for k in range(visits):
        speed = float(rng.uniform(*speed_range))
        side = rng.uniform(-math.pi, math.pi)
        near = float(rng.uniform(*_NEAR_RADIUS_M))
        walk_s = (_AWAY_RADIUS_M - near) / speed
        start = k * slot + float(rng.uniform(0.05, 0.3)) * slot
        stay = float(rng.uniform(0.2, 0.4)) * slot
        reach = np.array(waypoints[int(rng.integers(len(waypoints)))]) + rng.normal(0.0, 0.1, 3)
        reach[2] = float(np.clip(reach[2], 0.3, 1.2))
        away_xy = _AWAY_RADIUS_M * np.array([math.cos(side), math.sin(side)])
        near_xy = near * np.array([math.cos(side), math.sin(side)])
        yaw = side + math.pi  # facing the arm
        t_in = start + walk_s
        t_out = t_in + stay
        if t_out + walk_s >= duration_s + slot:
            break
        frames.append(PersonKeyframe(t=start, position=tuple(away_xy), yaw=yaw))
        frames.append(PersonKeyframe(t=t_in, position=tuple(near_xy), yaw=yaw, right_hand=tuple(reach)))
        frames.append(PersonKeyframe(t=t_out, position=tuple(near_xy), yaw=yaw, right_hand=tuple(reach)))
        frames.append(PersonKeyframe(t=t_out + walk_s, position=tuple(away_xy), yaw=yaw))
    return _strictly_increasing(frames)


def _standing(t: float, side: float) -> PersonKeyframe:
    xy = _AWAY_RADIUS_M * np.array([math.cos(side), math.sin(side)])
    return PersonKeyframe(t=t, position=(float(xy[0]), float(xy[1])), yaw=side + math.pi)


def _strictly_increasing(frames: list[PersonKeyframe]) -> list[PersonKeyframe]:
    out = [frames[0]]
    for f in frames[1:]:
        if f.t > out[-1].t + 1e-6:
            out.append(f)
    return out

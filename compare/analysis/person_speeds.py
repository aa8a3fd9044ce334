"""How fast a scenario's person moves: per keyframe segment, per body part over a run, over a sweep.

Each run records the fastest capsule end of each body part, sampled at the control rate
(:func:`compare.sensing.person_track.max_speeds_by_part`); a sweep gives the distribution of
those per-run maxima (median, 95th percentile, largest) per part, so that a campaign's report
states the people its verdict is about.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

import robots
from compare.config import Config
from compare.sensing.person import Person
from compare.sensing.person_track import PersonTrack, max_speeds_by_part


def part_max_speeds(config: Config, robot: robots.Robot) -> dict[str, float]:
    """The realized person's fastest capsule end per body part over the run, at the control rate [m/s]."""
    sc = config.scenario
    person = Person(robot.workcell_model(), config.person.keyframes, time_scale=sc.time_scale)
    return max_speeds_by_part(PersonTrack.from_person(person, sc.sim_time_s, sc.dt))


def resolved_hands(config: Config, robot: robots.Robot) -> list[tuple[np.ndarray, np.ndarray]]:
    """Right and left hand positions [m] of every keyframe, hanging hands resolved."""
    person = Person(robot.workcell_model(), config.person.keyframes, time_scale=1.0)
    poses = [person.pose_at(f.t) for f in config.person.keyframes]
    return [(p.hands["r"], p.hands["l"]) for p in poses]


def keyframe_speeds(config: Config, robot: robots.Robot | None = None) -> tuple[float, float]:
    """Fastest torso and hand speeds of a scenario's person over its motion segments [m/s].

    Real time (keyframe times × ``time_scale``); hands resolved (a keyframe without a target
    has its hanging hand). (0, 0) for a person who never moves.
    """
    frames = list(config.person.keyframes)
    if len(frames) < 2:
        return 0.0, 0.0
    hands = resolved_hands(config, robot or config.load_robot())
    torso = hand = 0.0
    for k in range(len(frames) - 1):
        dt = (frames[k + 1].t - frames[k].t) * config.scenario.time_scale
        torso = max(torso, math.dist(frames[k].position, frames[k + 1].position) / dt)
        hand = max(hand, *(float(np.linalg.norm(hands[k + 1][s] - hands[k][s])) / dt for s in (0, 1)))
    return torso, hand


def sweep_person_speeds(summaries: list[dict[str, Any]]) -> dict[str, dict[str, float]] | None:
    """``{part: {"median", "p95", "max", "runs"}}`` of the runs' per-part maximum speeds [m/s]; None without any."""
    values: dict[str, list[float]] = {}
    for s in summaries:
        for part, v in ((s.get("person") or {}).get("max_speed_mps") or {}).items():
            values.setdefault(part, []).append(float(v))
    if not values:
        return None
    return {
        part: {
            "median": float(np.median(v)),
            "p95": float(np.percentile(v, 95)),
            "max": float(np.max(v)),
            "runs": len(v),
        }
        for part, v in values.items()
    }


def report_lines(sweep_summary: dict[str, Any]) -> list[str]:
    """Markdown section of the sweep report on the realized person's speeds (empty without them)."""
    speeds = (sweep_summary.get("person") or {}).get("max_speed_mps")
    if not speeds:
        return []
    out = [
        "",
        "## The realized person",
        "",
        "| body part | runs | fastest per run: median [m/s] | p95 [m/s] | max [m/s] |",
        "|---|---:|---:|---:|---:|",
    ]
    out += [
        f"| {part} | {v['runs']} | {v['median']:.2f} | {v['p95']:.2f} | {v['max']:.2f} |" for part, v in speeds.items()
    ]
    out += [
        "",
        "Speed of the fastest capsule end of each body part, sampled at the control rate"
        " (compare/sensing/person_track.py); the family's walking and hand speeds bound them"
        " (compare/scenarios/random_scenario.py).",
    ]
    return out

"""The paper's claims as code, on hand-built step tables whose answer is known."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from compare.analysis.claims import (
    ClaimContext,
    PersonTimeline,
    TaskBand,
    check_claims,
    claims_table,
    context_from_config,
    person_timeline,
)
from compare.config import load_config

CONFIGS = Path(__file__).resolve().parents[3] / "configs"
INF = float("inf")
CPS = ("link_4", "link_6", "link_7")
JOINTS = {2: (0.92, 5.36), 4: (0.62, 5.66), 6: (1.23, 5.05)}


def _tasks(walls: bool = False) -> tuple[TaskBand, ...]:
    out = [TaskBand(f"joint_limit_{j}", "joint_limits", lo, hi, lo + 0.05, hi - 0.05) for j, (lo, hi) in JOINTS.items()]
    if walls:
        out += [TaskBand(f"wall_{a}_min", "walls", 0.0, INF, 0.03, INF) for a in ("z", "y")]
    out += [TaskBand(f"obstacle_{cp}", "obstacles", 0.35, INF, 0.40, INF) for cp in CPS]
    return tuple(out)


def _case1_steps() -> tuple[pd.DataFrame, ClaimContext]:
    """Person steps in at 2 s, in by 3 s, leaves at 6 s, gone at 7 s; everything as the paper says."""
    t = np.round(np.arange(0.0, 10.0, 0.01), 10)
    near = (t >= 3.0) & (t < 6.0)
    far = np.where(near, 0.38, 0.9)
    x = np.where(t < 3.2, 0.1 * t, 0.32)  # the EE moves, stops at 3.2 s while the tasks are active ...
    x = np.where(t >= 6.0, 0.32 + 0.1 * (t - 6.0), x)  # ... and resumes when the person leaves
    err = np.where(t < 7.5, 0.3, 0.01)
    err = np.where((t >= 0.8) & (t < 1.0) | (t >= 1.8) & (t < 1.9), 0.01, err)  # both waypoints before 2 s
    steps = pd.DataFrame(
        {
            "t": t,
            "ee_x": x,
            "ee_y": 0.4,
            "ee_z": 0.7,
            "ee_error_m": err,
            "waypoint": np.where((t >= 1.0) & (t < 8.0), 1, 0),
            "sigma:joint_limit_2": 2.0,
            "sigma:joint_limit_4": np.where((t > 1.0) & (t < 1.5), 0.64, 1.5),
            "sigma:joint_limit_6": 2.0,
            "sigma:obstacle_link_4": 0.8,
            "sigma:obstacle_link_6": far,
            "sigma:obstacle_link_7": far,
            "truth:obstacle_link_4": 0.8,
            "truth:obstacle_link_6": far,
            "truth:obstacle_link_7": far + 0.001,
        }
    )
    ctx = ClaimContext("case1", _tasks(), CPS, PersonTimeline(2.0, 3.0, 6.0, 7.0), 0.02)
    return steps, ctx


def _by_key(steps, ctx):
    return {c.key: c for c in check_claims(steps, ctx)}


def test_case1_claims_hold_when_the_run_does_what_the_paper_says():
    steps, ctx = _case1_steps()
    claims = _by_key(steps, ctx)
    assert list(claims) == [
        "c1_free_before",
        "c1_obstacle_tasks",
        "c1_arm_stops",
        "c1_distances",
        "c1_joint4_limit",
        "c1_resumes",
    ]
    assert all(c.holds for c in claims.values()), {k: c.measured for k, c in claims.items()}
    assert claims["c1_distances"].values["min_distance_m"] == pytest.approx(0.38)
    assert claims["c1_joint4_limit"].values["margin_rad"] == pytest.approx(0.02)
    assert claims["c1_resumes"].values["waypoint_reached_s"] == pytest.approx(7.5)
    assert claims["c1_free_before"].values["waypoints_reached"] == [0, 1]


def test_case1_free_before_needs_both_waypoints_a_distant_person_and_no_activation():
    steps, ctx = _case1_steps()
    one = steps.assign(ee_error_m=np.where(steps.t.between(1.8, 1.9), 0.3, steps.ee_error_m))
    assert not _by_key(one, ctx)["c1_free_before"].holds  # only waypoint 0 reached before 2 s
    near = steps.assign(**{"truth:obstacle_link_6": np.where(steps.t.between(1.0, 1.2), 0.39, 0.9)})
    claim = _by_key(near, ctx)["c1_free_before"]
    assert not claim.holds and claim.values["min_distance_m"] == pytest.approx(0.39)  # inside the activation band
    seen = steps.assign(
        **{"sigma:obstacle_link_7": np.where(steps.t.between(1.0, 1.2), 0.39, steps["sigma:obstacle_link_7"])}
    )
    assert not _by_key(seen, ctx)["c1_free_before"].holds  # a task activated on the measured distance


def test_case1_each_claim_fails_on_its_own_defect():
    steps, ctx = _case1_steps()
    elbow = steps.assign(**{"sigma:obstacle_link_4": np.where(steps.t.between(4, 5), 0.39, 0.8)})
    assert not _by_key(elbow, ctx)["c1_obstacle_tasks"].holds  # a third task activated

    moving = steps.assign(ee_x=0.05 * steps.t)  # keeps going at 5 cm/s
    stops = _by_key(moving, ctx)["c1_arm_stops"]
    assert not stops.holds and stops.values["median_progress_mps"] == pytest.approx(0.05, rel=1e-3)
    assert stops.values["window_s"] == pytest.approx([4.0, 6.0])  # 1 s after arrival and activation (3 s)
    creeping = steps.assign(ee_x=np.where(steps.t < 4.5, 0.5 * steps.t, 2.25))  # moves 0.5 s, then still
    slow = _by_key(creeping, ctx)["c1_arm_stops"]
    assert not slow.holds  # one of the two 1 s windows progressed by 0.25 m: median 0.125 m/s
    chatter = steps.assign(ee_x=0.32 + 0.02 * np.sin(2 * np.pi * 5 * steps.t))  # 5 Hz, ±2 cm, in place
    shaking = _by_key(chatter, ctx)["c1_arm_stops"]
    assert shaking.holds and shaking.values["mean_speed_mps"] > 0.3  # lots of path, no progress
    around = moving.assign(waypoint=np.where(moving.t < 5.0, 1, 0))
    assert not _by_key(around.assign(ee_x=steps.ee_x), ctx)["c1_arm_stops"].holds  # reached a waypoint

    close = steps.assign(**{"truth:obstacle_link_6": np.where(steps.t.between(4, 4.5), 0.34, 0.9)})
    dist = _by_key(close, ctx)["c1_distances"]
    assert not dist.holds and dist.values["min_distance_m"] == pytest.approx(0.34)
    assert "link_6 at 4.0 s" in dist.measured

    within_tolerance = steps.assign(**{"truth:obstacle_link_6": np.where(steps.t.between(4, 4.5), 0.3495, 0.9)})
    assert _by_key(within_tolerance, ctx)["c1_distances"].holds  # 0.5 mm: the metrics' 1 mm tolerance

    never = steps.assign(**{"sigma:joint_limit_4": 1.5})
    assert not _by_key(never, ctx)["c1_joint4_limit"].holds
    past = steps.assign(**{"sigma:joint_limit_4": np.where(steps.t.between(1, 1.2), 0.61, 1.5)})
    assert not _by_key(past, ctx)["c1_joint4_limit"].holds

    stuck = steps.assign(**{"sigma:obstacle_link_7": np.where(steps.t >= 3.0, 0.38, 0.9)})
    assert not _by_key(stuck, ctx)["c1_resumes"].holds  # still active after the person left


def test_case2_claims():
    t = np.round(np.arange(0.0, 9.0, 0.01), 10)
    pushed = (t > 2.0) & (t < 4.0)
    steps = pd.DataFrame(
        {
            "t": t,
            "ee_x": 0.1,
            "ee_y": 0.2,
            "ee_z": np.where(pushed, 0.21, 0.45),
            "ee_error_m": np.where(t < 6.0, 0.2, 0.0),
            "sigma:joint_limit_2": 2.0,
            "sigma:joint_limit_4": 2.0,
            "sigma:joint_limit_6": 2.0,
            "sigma:wall_z_min": np.where(pushed, 0.01, 0.25),
            "sigma:wall_y_min": 0.7,
            **{f"sigma:obstacle_{cp}": 0.5 for cp in CPS},
            **{f"truth:obstacle_{cp}": 0.5 for cp in CPS},
            "sigma:obstacle_link_7": np.where(pushed, 0.39, 0.5),
        }
    )
    ctx = ClaimContext("case2", _tasks(walls=True), CPS, PersonTimeline(1.0, 5.0, 1.0, 5.0), 0.02)
    claims = _by_key(steps, ctx)
    assert list(claims) == [
        "c2_moves_away",
        "c2_inside_box",
        "c2_distances",
        "c2_joint_limits",
        "c2_returns",
        "c2_chattering",
    ]
    assert all(c.holds for c in claims.values()), {k: c.measured for k, c in claims.items()}
    assert claims["c2_inside_box"].values["walls_activated"] == ["wall_z_min"]
    assert claims["c2_returns"].values["returned_s"] == pytest.approx(6.0)
    assert claims["c2_moves_away"].values["ee_displacement_m"] == pytest.approx(0.24)
    assert claims["c2_chattering"].values == {"toggles_moving": 2, "toggles_still": 0}
    through = steps.assign(**{"sigma:wall_z_min": np.where(pushed, -0.01, 0.25)})
    assert not _by_key(through, ctx)["c2_inside_box"].holds
    loose = steps.assign(**{"sigma:wall_z_min": 0.25})
    assert not _by_key(loose, ctx)["c2_inside_box"].holds  # the walls never had to act
    stays = steps.assign(ee_z=np.where(pushed, 0.42, 0.45))
    assert not _by_key(stays, ctx)["c2_moves_away"].holds  # 3 cm < 5 cm
    unseen = steps.assign(**{"sigma:obstacle_link_7": 0.5})
    assert not _by_key(unseen, ctx)["c2_moves_away"].holds  # moved, but no obstacle task acted
    chatter = steps.assign(**{"sigma:obstacle_link_7": np.where(pushed | ((t > 7.5) & (t < 7.6)), 0.39, 0.5)})
    claim = _by_key(chatter, ctx)["c2_chattering"]
    assert not claim.holds and claim.values["toggles_still"] == 2  # on and off 2.5 s after the person stopped


def test_person_timeline_of_case_configs():
    config, _ = load_config(CONFIGS / "case1.toml")
    assert person_timeline(config.person.keyframes) == PersonTimeline(35.0, 37.0, 55.0, 57.0)
    scaled = person_timeline(config.person.keyframes, 0.5)
    assert scaled == PersonTimeline(17.5, 18.5, 27.5, 28.5)
    ctx = context_from_config(config)
    assert ctx.control_points == CPS and [t.name for t in ctx.group("joint_limits")][1] == "joint_limit_4"
    band = ctx.group("obstacles")[0]
    assert (band.safety_lower, band.activation_lower) == pytest.approx((0.35, 0.40))


def test_claims_table_rows_per_claim_and_method():
    steps, ctx = _case1_steps()
    claims = check_claims(steps, ctx)
    bad = [dataclasses.replace(c, holds=False) for c in claims]
    text = claims_table([("slow", {"a": claims, "b": bad}), ("fast", {"a": bad})])
    lines = text.splitlines()
    assert lines[0] == "| claim | method | slow | fast |"
    assert len(lines) == 2 + 2 * len(claims)
    assert lines[2].startswith("| before the person steps in, the arm reaches both waypoints") and "| a | ✓" in lines[2]
    assert lines[3].startswith("|  | b | ✗") and lines[3].endswith("| – |")

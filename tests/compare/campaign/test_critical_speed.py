"""Critical approach speed: re-timing the person, the kinematic bound, and a 2-speed run end to end."""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import numpy as np
import pytest
from scipy.optimize import linprog
from typer.testing import CliRunner

from compare.analysis.critical_speed_results import HAND_RANGE_MPS, TORSO_RANGE_MPS, hand_speed
from compare.analysis.person_speeds import keyframe_speeds, resolved_hands
from compare.campaign.critical_speed import (
    critical,
    default_speeds,
    directions,
    retime_keyframes,
    retreat_speed_bound,
    rotate_keyframes,
)
from compare.cli import app
from compare.config import PersonKeyframe, load_config

CONFIGS = Path(__file__).resolve().parents[3] / "configs"


def test_hand_speed_spans_both_ranges_monotonically():
    assert hand_speed(TORSO_RANGE_MPS[0]) == pytest.approx(HAND_RANGE_MPS[0])
    assert hand_speed(TORSO_RANGE_MPS[1]) == pytest.approx(HAND_RANGE_MPS[1])
    speeds = default_speeds()
    assert len(speeds) >= 12 and speeds[0] == pytest.approx(0.1) and speeds[-1] == pytest.approx(1.6)
    assert np.all(np.diff([hand_speed(v) for v in speeds]) > 0)


def test_retime_moves_at_the_speeds_and_holds_keep_their_end():
    frames = [
        PersonKeyframe(t=0.0, position=(0.0, 1.4)),
        PersonKeyframe(t=5.0, position=(0.0, 1.4)),
        PersonKeyframe(t=7.0, position=(0.0, 1.0), right_hand=(0.0, 0.6, 0.8)),
        PersonKeyframe(t=15.0, position=(0.0, 1.0), right_hand=(0.0, 0.6, 0.8)),
        PersonKeyframe(t=16.0, position=(0.0, 1.4)),
    ]
    hands = [
        (np.array([0.0, 1.3, 0.0]), np.zeros(3)),
        (np.array([0.0, 1.3, 0.0]), np.zeros(3)),
        (np.array([0.0, 0.6, 0.8]), np.array([0.0, -0.4, 0.0])),
        (np.array([0.0, 0.6, 0.8]), np.array([0.0, -0.4, 0.0])),
        (np.array([0.0, 1.3, 0.0]), np.zeros(3)),
    ]
    hand_step = math.hypot(0.7, 0.8)
    out = retime_keyframes(frames, hands, torso_mps=0.2, hand_mps=10.0)
    assert [f.t for f in out] == pytest.approx([0.0, 5.0, 7.0, 15.0, 17.0])  # torso-limited: 0.4 m / 0.2 m/s
    out = retime_keyframes(frames, hands, torso_mps=10.0, hand_mps=0.5)
    assert [f.t for f in out][:3] == pytest.approx([0.0, 5.0, 5.0 + hand_step / 0.5])  # hand-limited
    assert out[3].t == pytest.approx(15.0)
    slow = retime_keyframes(frames, hands, torso_mps=0.02, hand_mps=10.0, time_scale=0.5)
    assert slow[2].t == pytest.approx(5.0 + 20.0 / 0.5)  # 20 s of real time is 40 s of keyframe time
    assert slow[3].t == pytest.approx(slow[2].t + 0.05 / 0.5)  # the hold is over before it starts
    assert all(b.t > a.t for a, b in zip(slow, slow[1:], strict=False))
    assert [(f.position, f.right_hand) for f in out] == [(f.position, f.right_hand) for f in frames]


def test_rotation_turns_the_path_about_the_base_axis():
    frames = [PersonKeyframe(t=0.0, position=(0.0, 1.0), yaw=-math.pi / 2, right_hand=(0.0, 0.5, 0.8))]
    (turned,) = rotate_keyframes(frames, math.pi / 2)
    assert turned.position == pytest.approx((-1.0, 0.0))
    assert turned.right_hand == pytest.approx((-0.5, 0.0, 0.8))
    assert turned.yaw == pytest.approx(0.0)


def test_directions_start_with_the_case_and_are_reproducible():
    dirs = directions(4, 20.0, 2.0)
    assert (dirs[0].angle_rad, dirs[0].shift_s) == (0.0, 0.0)
    assert dirs == directions(4, 20.0, 2.0)
    assert all(abs(d.angle_rad) <= math.radians(20.0) and abs(d.shift_s) <= 2.0 for d in dirs)
    assert len({d.angle_rad for d in dirs}) == 4


def test_critical_speed_is_the_top_of_the_held_prefix():
    assert critical([(0.4, False), (0.1, True), (0.2, True), (0.8, True)]) == 0.2
    assert critical([(0.1, False), (0.2, True)]) is None
    assert critical([(0.1, True), (0.2, True)]) == 0.2


def test_kinematic_bound_is_the_linear_program_over_the_velocity_box(jaco):
    rng = np.random.default_rng(1)
    for _ in range(5):
        q = jaco.home + rng.uniform(-0.4, 0.4, jaco.nq)
        kin = jaco.kinematics(q)
        u = rng.normal(size=3)
        u /= np.linalg.norm(u)
        c = -(u @ kin.position_jacobian("link_7"))
        lp = linprog(c, bounds=[(-v, v) for v in jaco.v_max], method="highs")
        assert retreat_speed_bound(kin, "link_7", u, jaco.v_max) == pytest.approx(-lp.fun, rel=1e-9)


@pytest.mark.parametrize("case", ["case1", "case2", "case1_paper", "case2_paper"])
def test_case_configs_state_the_keyframe_speeds(case, jaco):
    text = (CONFIGS / f"{case}.toml").read_text()
    stated = re.search(r"torso ([\d.]+) m/s, hand ([\d.]+) m/s", text)
    assert stated, f"{case}.toml does not state the person's speeds"
    config, _ = load_config(CONFIGS / f"{case}.toml")
    torso, hand = keyframe_speeds(config, jaco)
    assert float(stated.group(1)) == pytest.approx(torso, abs=0.006)
    assert float(stated.group(2)) == pytest.approx(hand, abs=0.006)


def test_bad_options_are_one_line_and_exit_2(tmp_path):
    runner = CliRunner()
    res = runner.invoke(app, ["critical-speed", str(CONFIGS / "case2.toml"), "--speeds", "a,b", "--out", str(tmp_path)])
    assert res.exit_code == 2 and "--speeds" in res.output
    res = runner.invoke(app, ["critical-speed", str(CONFIGS / "random.toml"), "--out", str(tmp_path)])
    assert res.exit_code == 2 and "scenario.kind" in res.output


@pytest.mark.slow
def test_critical_speed_two_speeds_end_to_end(tmp_path, jaco):
    out = tmp_path / "crit"
    args = ["critical-speed", str(CONFIGS / "case2.toml"), "--speeds", "0.3,1.2", "--seeds", "1", "-m", "tpik"]
    args += ["--time-scale", "0.2", "--oracle", "--out", str(out), "-q"]
    res = CliRunner().invoke(app, args)
    assert res.exit_code == 0, res.output
    result = json.loads((out / "critical_speed.json").read_text())
    assert set(result) == {"tpik"} and set(result["tpik"]) == {"safety_mps", "physical_mps", "curve"}
    curve = result["tpik"]["curve"]
    assert [v for v, _ in curve] == pytest.approx([0.3, 1.2])
    held = []
    for v, d in curve:
        run = out / "runs" / f"v{v:.3f}-s0"
        summary = json.loads((run / "summary.json").read_text())
        m = summary["methods"]["tpik"]
        assert d == pytest.approx(min(x for x in m["min_obstacle_distance_m"] if x is not None))
        held.append((v, m["obstacles"]["violations"] == 0))
        assert "oracle" in summary and "obstacle_violations" in m
        cfg, _ = load_config(run / "config.toml")
        torso, hand = keyframe_speeds(cfg, jaco)
        assert torso <= v + 1e-9 and hand <= hand_speed(v) + 1e-9
        assert math.isclose(torso, v, rel_tol=1e-6) or math.isclose(hand, hand_speed(v), rel_tol=1e-6)
    assert result["tpik"]["safety_mps"] == critical(held)
    detail = json.loads((out / "critical_speed_detail.json").read_text())
    assert detail["oracle"]["curve"][0][0] == pytest.approx(0.3)
    assert set(detail["kinematic_bound_mps"]) == {"link_4", "link_6", "link_7"}
    assert (out / "critical_speed.png").stat().st_size > 10_000
    claims = json.loads((out / "claims_at_critical.json").read_text())
    crit = result["tpik"]["safety_mps"]
    assert claims["tpik"]["critical"] is (crit is not None)
    assert claims["tpik"]["speed_mps"] == pytest.approx(crit if crit is not None else 0.3)  # else the slowest
    keys = {c["key"] for c in claims["tpik"]["claims"]}
    assert keys == {"c2_moves_away", "c2_inside_box", "c2_distances", "c2_joint_limits", "c2_returns", "c2_chattering"}
    table = CliRunner().invoke(app, ["claims", str(out), "--out", str(tmp_path / "claims.md")])
    assert table.exit_code == 0, table.output
    text = (tmp_path / "claims.md").read_text()
    assert "each method's critical speed" in text and "| tpik |" in text
    assert json.loads((tmp_path / "claims.json").read_text())
    stamp = (out / "runs" / "v0.300-s0" / "summary.json").stat().st_mtime_ns
    assert CliRunner().invoke(app, args).exit_code == 0
    assert (out / "runs" / "v0.300-s0" / "summary.json").stat().st_mtime_ns == stamp  # resumed, not redone


def test_resolved_hands_put_a_hanging_hand_below_the_shoulder(jaco):
    config, _ = load_config(CONFIGS / "case1.toml")
    hands = resolved_hands(config, jaco)
    assert len(hands) == len(config.person.keyframes)
    raised = [k for k, f in enumerate(config.person.keyframes) if f.right_hand is not None]
    for k in raised:
        assert hands[k][0] == pytest.approx(config.person.keyframes[k].right_hand)
    hanging = hands[0][0]
    assert hanging[2] < 0.3  # hanging: well below a raised hand (shoulder ≈ 0.65 m above the table)

"""ISO/TS 15066 clause 5.5.4 margin: the formula against hand-computed cases, the speed estimate, a run."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import robots
from compare.analysis.iso15066 import (
    IsoParameters,
    SeparationMonitor,
    protective_separation_distance,
    separation_margin,
    separation_terms,
)
from compare.config import ConfigError, Iso15066Config, load_config, parse_config
from compare.run import run_method
from compare.sensing.results import DistanceResult, ObstacleReading
from compare.sensing.scene import control_point_positions

CONFIGS = Path(__file__).resolve().parents[3] / "configs"
DEFAULTS = IsoParameters()  # T_r 0.1 s, T_s 0.2 s, S_s = v_r T_s / 2, C 0, Z_d 0.02 m, Z_r 0.01 m


def test_defaults_are_the_documented_ones():
    cfg = Iso15066Config()
    assert IsoParameters.from_config(cfg) == DEFAULTS
    assert (cfg.reaction_time_s, cfg.stopping_time_s, cfg.intrusion_distance_m) == (0.1, 0.2, 0.0)
    assert (cfg.sensor_uncertainty_m, cfg.robot_uncertainty_m, cfg.human_speed) == (0.02, 0.01, "estimated")


def test_walking_person_and_moving_robot_by_hand():
    # S_h = 1.6 (0.1 + 0.2) = 0.48; S_r = 0.5 · 0.1 = 0.05; S_s = 0.5 · 0.2 / 2 = 0.05; C + Z_d + Z_r = 0.03.
    terms = separation_terms(1.6, 0.5, DEFAULTS)
    assert terms["S_h"] == pytest.approx(0.48)
    assert terms["S_r"] == pytest.approx(0.05)
    assert terms["S_s"] == pytest.approx(0.05)
    assert protective_separation_distance(1.6, 0.5, DEFAULTS) == pytest.approx(0.61)
    assert separation_margin(1.0, 1.6, 0.5, DEFAULTS) == pytest.approx(0.39)


def test_configured_stopping_distance_and_intrusion_replace_the_defaults():
    params = IsoParameters(
        reaction_time_s=0.05,
        stopping_time_s=0.3,
        stopping_distance_m=0.12,
        intrusion_distance_m=0.85,
        sensor_uncertainty_m=0.0,
        robot_uncertainty_m=0.0,
    )
    # S_h = 2.0 · 0.35 = 0.70; S_r = 1.0 · 0.05 = 0.05; S_s = 0.12 (given); C = 0.85.
    assert protective_separation_distance(2.0, 1.0, params) == pytest.approx(0.70 + 0.05 + 0.12 + 0.85)


def test_standing_person_and_robot_at_rest_leave_only_the_uncertainties():
    assert protective_separation_distance(0.0, 0.0, DEFAULTS) == pytest.approx(0.03)


def test_the_formula_broadcasts_over_steps():
    v_h = np.array([0.0, 1.0, 2.0])
    out = protective_separation_distance(v_h, 0.2, DEFAULTS)
    expected = v_h * 0.3 + 0.2 * 0.1 + 0.2 * 0.2 / 2 + 0.03
    np.testing.assert_allclose(out, expected)


class _MovingPoint:
    """A source whose closest point to link_4 moves with a constant velocity [m/s]."""

    def __init__(self, kin, velocity, start_offset):
        self.p = control_point_positions(kin, ("link_4",))["link_4"]
        self.v = np.asarray(velocity, dtype=float)
        self.o0 = self.p + np.asarray(start_offset, dtype=float)

    def update(self, t, kin):
        o = self.o0 + self.v * t
        reading = ObstacleReading(float(np.linalg.norm(o - self.p)), o, True)
        return DistanceResult({"link_4": reading}, 1.0, False, t)


@pytest.mark.parametrize(
    ("velocity", "expected"),
    [((0.0, -1.0, 0.0), 1.0), ((0.0, 0.0, 1.0), 0.0), ((0.0, 1.0, 0.0), 0.0)],
    ids=["approaching", "sideways", "receding"],
)
def test_human_speed_is_estimated_from_the_measured_closest_points(jaco, velocity, expected):
    kin = jaco.kinematics(jaco.home)
    monitor = SeparationMonitor(_MovingPoint(kin, velocity, (0.0, 1.0, 0.0)), None, ("link_4",))
    for k in range(30):
        monitor.update(k / 30.0, kin)
    _, v_h, points = monitor.human_speeds(Iso15066Config())
    assert v_h["link_4"][-1] == pytest.approx(expected, abs=0.02)
    assert np.all(np.isfinite(points["link_4"]))


def _numpy_speeds(monitor: SeparationMonitor, cfg: Iso15066Config) -> dict[str, np.ndarray]:
    """The estimate of the module docstring with numpy's vector products, update by update (the reference)."""
    ups = [u for u in monitor.updates if u.usable]
    out = {}
    for c, cp in enumerate(monitor.frames):
        v, est, prev = np.zeros(len(ups)), 0.0, None
        for k, u in enumerate(ups):
            if np.isnan(u.points[c, 0]):  # nothing in range
                est, prev = 0.0, None
                continue
            point = u.points[c]
            if cfg.human_speed == "constant":
                est = cfg.human_speed_mps
            elif prev is not None and u.t > prev[0]:
                gap = u.t - prev[0]
                away = u.control_points[c] - point
                n = float(np.linalg.norm(away))
                raw = float((point - prev[1]) @ away) / (n * gap) if n > 1e-9 else 0.0
                raw = min(max(raw, 0.0), cfg.human_speed_max_mps)
                est += gap / (cfg.human_speed_filter_s + gap) * (raw - est)
            prev = (u.t, point)
            v[k] = est
        out[cp] = v
    return out


class _Jumpy:
    """Random closest points of two control points, sometimes out of range, sometimes at a repeated time."""

    def __init__(self, rng: np.random.Generator) -> None:
        self.rng = rng
        self.missing = {"link_4": 0, "link_6": 0}  # updates without a point in range, per control point

    def update(self, t, kin):
        readings = {}
        for cp in ("link_4", "link_6"):
            if self.rng.random() < 0.15:
                self.missing[cp] += 1
                continue
            o = self.rng.normal(scale=0.4, size=3)
            in_range = bool(self.rng.random() < 0.9)
            self.missing[cp] += not in_range
            readings[cp] = ObstacleReading(float(np.linalg.norm(o)), o, in_range)
        return DistanceResult(readings, 1.0, False, t)


@pytest.mark.parametrize("mode", ["estimated", "constant"])
def test_the_compiled_estimate_is_the_numpy_one_bit_for_bit(jaco, mode):
    """Random points, gaps out of range, repeated times, moving control points: the same numbers exactly."""
    rng = np.random.default_rng(9)
    cfg = Iso15066Config(human_speed=mode, human_speed_filter_s=0.07)
    source = _Jumpy(rng)
    monitor = SeparationMonitor(source, None, ("link_4", "link_6"))
    t = 0.0
    for _ in range(400):
        q = jaco.home + rng.normal(scale=0.3, size=jaco.nq)
        t += 0.0 if rng.random() < 0.05 else 1.0 / 30.0
        monitor.update(t, jaco.kinematics(q))
    _, v_h, points = monitor.human_speeds(cfg)
    want = _numpy_speeds(monitor, cfg)
    for cp in monitor.frames:
        assert np.array_equal(v_h[cp], want[cp])
        assert np.isnan(points[cp][:, 0]).sum() == source.missing[cp] > 0
    assert mode == "constant" or np.count_nonzero(np.diff(v_h["link_4"])) > 100


def test_constant_human_speed_mode_uses_the_configured_speed(jaco):
    kin = jaco.kinematics(jaco.home)
    monitor = SeparationMonitor(_MovingPoint(kin, (0.0, 0.0, 0.0), (0.0, 1.0, 0.0)), None, ("link_4",))
    for k in range(3):
        monitor.update(k / 30.0, kin)
    _, v_h, _ = monitor.human_speeds(Iso15066Config(human_speed="constant", human_speed_mps=1.6))
    assert np.all(v_h["link_4"] == 1.6)


def test_margins_from_the_recorded_control_points_equal_those_recomputed_from_q(jaco):
    rng = np.random.default_rng(3)
    n, frames = 40, ("link_4", "link_6")
    qs = jaco.home + 0.02 * np.cumsum(rng.standard_normal((n, jaco.nq)), axis=0)
    t = np.arange(n) / 100.0
    source = _MovingPoint(jaco.kinematics(jaco.home), (0.0, -1.0, 0.0), (0.0, 0.6, 0.0))
    monitor = SeparationMonitor(source, None, frames)
    known = np.full((n, len(frames), 3), np.nan)
    for i in range(n):
        kin = jaco.kinematics(qs[i])
        if i % 3 == 0:
            monitor.update(t[i], kin)
        if i % 7:  # every seventh step not recorded: computed from q
            kin.frame_positions(frames, known[i])
    steps = pd.DataFrame({"t": t, **{f"q_{j + 1}": qs[:, j] for j in range(jaco.nq)}})
    cfg = Iso15066Config()
    recomputed = monitor.margins(steps, jaco, cfg)
    assert np.isfinite(recomputed["iso_margin_m:link_4"]).sum() > 30
    pd.testing.assert_frame_equal(monitor.margins(steps, jaco, cfg, known), recomputed, check_exact=True)
    moved = known + 0.01  # the recorded points are what is used
    assert not monitor.margins(steps, jaco, cfg, moved).equals(recomputed)
    with pytest.raises(ValueError, match=r"shape \(40, 2, 3\)"):
        monitor.margins(steps, jaco, cfg, known[:, :1])


def test_bad_iso_config_names_the_key():
    config, _ = load_config(CONFIGS / "case1.toml")
    data = config.model_dump(mode="python")
    data["iso15066"] = {"reaction_time_s": -0.1}
    with pytest.raises(ConfigError, match=r"^iso15066\.reaction_time_s"):
        parse_config(data)
    data["iso15066"] = {"reaction_tim_s": 0.1}
    with pytest.raises(ConfigError, match=r"^iso15066\.reaction_tim_s: unknown key"):
        parse_config(data)


@pytest.fixture(scope="module")
def fast_approach() -> dict:
    """The person walks in at 1.6 m/s and thrusts a hand at link_4 at 2 m/s: faster than the arm retreats."""
    config, _ = load_config(CONFIGS / "case1.toml")
    data = config.model_dump(mode="python")
    data["scenario"].update(duration_s=2.5, time_scale=1.0, sensing="geometric")
    data["methods"] = {"names": ["tpik"], "settings": {}}
    data["waypoints"]["positions"] = []  # hold the start pose
    data["person"] = {
        "keyframes": [
            {"t": 0.0, "position": (0.0, 1.6), "yaw": -1.5708},
            {"t": 0.3, "position": (0.0, 1.6), "yaw": -1.5708},
            # 0.8 m at 1.6 m/s, the hand raised toward link_4 on the way.
            {"t": 0.8, "position": (0.0, 0.8), "yaw": -1.5708, "right_hand": (0.0, 0.55, 0.7)},
            # The hand thrusts 0.4 m toward link_4 (at y ≈ 0.12, z ≈ 0.67) in 0.2 s: 2 m/s.
            {"t": 1.0, "position": (0.0, 0.8), "yaw": -1.5708, "right_hand": (0.0, 0.15, 0.68)},
            {"t": 2.5, "position": (0.0, 0.8), "yaw": -1.5708, "right_hand": (0.0, 0.15, 0.68)},
        ]
    }
    robot = robots.load("jaco2")
    return run_method(parse_config(data), "tpik", robot)


def test_a_person_faster_than_the_arm_drives_the_margin_negative(fast_approach):
    iso = fast_approach["summary"]["iso15066"]
    assert iso["min_margin_m"] < 0.0
    assert iso["time_below_zero_s"] > 0.0
    assert iso["per_control_point"]["link_4"]["min_margin_m"] < 0.0
    # The estimate sees the approach (walking 1.6 m/s, hand 2 m/s), within the clip.
    assert 0.8 < iso["human_speed_max_mps"] <= Iso15066Config().human_speed_max_mps
    assert iso["parameters"]["reaction_time_s"] == 0.1


def test_margin_columns_match_the_formula_step_by_step(fast_approach):
    steps = fast_approach["steps"]
    m = steps["iso_margin_m:link_4"].to_numpy()
    ok = np.isfinite(m)
    assert ok.sum() > 50
    s_p = protective_separation_distance(
        steps["iso_vh_mps:link_4"].to_numpy()[ok], steps["iso_vr_mps:link_4"].to_numpy()[ok], DEFAULTS
    )
    np.testing.assert_allclose(steps["iso_sp_m:link_4"].to_numpy()[ok], s_p)
    # The measured distance behind the margin is the controller's σ of the obstacle task.
    sigma = steps["sigma:obstacle_link_4"].to_numpy()[ok]
    np.testing.assert_allclose(m[ok] + s_p, sigma, atol=1e-9)


def test_no_person_in_range_means_no_margin(jaco):
    config, _ = load_config(CONFIGS / "case1.toml")
    data = config.model_dump(mode="python")
    data["scenario"].update(duration_s=0.5, sensing="geometric")
    data["methods"] = {"names": ["tpik"], "settings": {}}
    data["person"] = {"keyframes": []}
    summary = run_method(parse_config(data), "tpik", jaco)["summary"]
    assert summary["iso15066"]["min_margin_m"] is None
    assert summary["iso15066"]["time_below_zero_s"] == 0.0

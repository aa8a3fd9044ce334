"""The obstacle motion estimate and the predictions handed to the obstacle tasks (compare.sensing.prediction).

The estimate is checked against known motions (constant velocity with noise and dropout, a jump
to another body part, a point assumed from occluded space); the predictions against their
definitions: the nearest point of the horizon, the closing speed, the growth; the truth against
distances computed here from a person walking straight at a control point.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
import pytest

from compare.sensing.motion_estimate import MotionFilterSettings, PointMotionFilter
from compare.sensing.person_track import PersonTrack
from compare.sensing.prediction import (
    EstimatedPrediction,
    PredictionSettings,
    TruePrediction,
    nearest_on_path,
)

PERIOD_S = 1.0 / 30.0


@dataclass
class _Reading:
    closest_point: np.ndarray | None
    in_range: bool = True
    occluded: bool = False
    surface_point: np.ndarray | None = None


class _Kin:
    """Just the control points' positions."""

    def __init__(self, positions: dict[str, np.ndarray]) -> None:
        self.positions = positions

    def frame_position(self, name: str) -> np.ndarray:
        return self.positions[name]


def _velocity_errors(noise_m: float, acceleration_mps2: float, seed: int = 0) -> np.ndarray:
    """Median over 20 tracks of the velocity error after each of 31 frames (10 % dropped) [m/s]."""
    rng = np.random.default_rng(seed)
    v = np.array([-1.2, 0.4, 0.0])
    errors = np.full((20, 31), np.nan)
    for trial in range(20):
        f = PointMotionFilter(MotionFilterSettings(acceleration_mps2=acceleration_mps2))
        p0 = rng.normal(size=3)
        for k in range(31):
            if 0 < k < 30 and rng.random() < 0.1:
                continue
            t = k * PERIOD_S
            errors[trial, k] = float(np.linalg.norm(f.update(t, p0 + v * t + rng.normal(scale=noise_m, size=3)) - v))
        assert f.restarts == 0
    return np.nanmedian(errors, axis=0)


def test_filter_finds_a_constant_velocity():
    """Exact points: the velocity within 2 cm/s after 0.1 s (the first frame knows none)."""
    err = _velocity_errors(0.0, 8.0)
    assert err[0] == pytest.approx(float(np.linalg.norm([-1.2, 0.4, 0.0])))
    assert err[3:].max() < 0.02


def test_filter_trades_noise_for_lag():
    """1 cm noise: the steady error stays below 0.3 m/s at a = 8 m/s², and a smaller a filters more."""
    default, slow = _velocity_errors(0.01, 8.0)[10:], _velocity_errors(0.01, 4.0)[10:]
    assert np.median(default) < 0.3
    assert np.median(slow) < 0.8 * np.median(default)


def test_filter_restarts_on_a_jump_and_keeps_the_velocity():
    """The closest point jumps 0.3 m (another body part): a new track, not a 9 m/s spike."""
    f = PointMotionFilter(MotionFilterSettings())
    v = np.array([1.0, 0.0, 0.0])
    for k in range(20):
        f.update(k * PERIOD_S, v * k * PERIOD_S)
    before = f.velocity
    est = f.update(20 * PERIOD_S, v * 20 * PERIOD_S + np.array([0.0, 0.3, 0.0]))
    assert f.restarts == 1
    np.testing.assert_allclose(est, before)
    assert float(np.linalg.norm(est)) < 1.5


def test_an_occluded_point_moves_the_estimate_less():
    """A 5 cm step seen as measured moves the velocity more than the same step assumed from occlusion."""
    moved = []
    for occluded in (False, True):
        f = PointMotionFilter(MotionFilterSettings())
        for k in range(10):
            f.update(k * PERIOD_S, np.zeros(3))
        moved.append(float(np.linalg.norm(f.update(10 * PERIOD_S, np.array([0.05, 0.0, 0.0]), occluded))))
    assert moved[1] < 0.5 * moved[0]


def test_same_frame_twice_changes_nothing_and_reset_ends_the_track():
    f = PointMotionFilter(MotionFilterSettings())
    f.update(0.0, np.zeros(3))
    f.update(PERIOD_S, np.array([0.03, 0.0, 0.0]))
    v = f.velocity
    np.testing.assert_array_equal(f.update(PERIOD_S, np.array([0.5, 0.0, 0.0])), v)
    f.reset()
    assert not f.tracking and not f.velocity.any()


def test_nearest_on_path():
    o, v = np.array([1.0, 0.0, 0.0]), np.array([-1.0, 0.0, 0.0])
    np.testing.assert_allclose(nearest_on_path(np.zeros(3), o, v, 0.5), [0.5, 0.0, 0.0])  # end of the path
    np.testing.assert_allclose(nearest_on_path(np.zeros(3), o, v, 2.0), [0.0, 0.0, 0.0])  # passes through P
    np.testing.assert_allclose(nearest_on_path(np.zeros(3), o, -v, 1.0), o)  # moving away: O itself
    np.testing.assert_allclose(nearest_on_path(np.zeros(3), o, v, 0.0), o)  # no horizon


def _approach(settings: PredictionSettings, speed: float, frames: int = 30) -> list:
    """A point walking straight at the control point (at the origin) from 1.2 m, seen at 30 Hz."""
    pred = EstimatedPrediction(settings, ["cp"])
    kin = _Kin({"cp": np.zeros(3)})
    out = []
    for k in range(frames):
        t = k * PERIOD_S
        point = np.array([1.2 - speed * t, 0.0, 0.0])
        out.append(pred.predict(t, {"cp": _Reading(point)}, kin)["cp"])  # type: ignore[arg-type]
    return out


def test_estimated_prediction_of_an_approach():
    """After 1 s at 0.8 m/s: closing ≈ 0.8, the horizon point 0.5 × 0.8 m nearer, growth f (T_r + T_s)."""
    settings = PredictionSettings(horizon_s=0.5, growth_time_s=0.3)
    last = _approach(settings, 0.8)[-1]
    assert last.closing_mps == pytest.approx(0.8, abs=0.05)
    assert last.feedforward_mps == last.closing_mps
    assert last.growth_m == pytest.approx(0.3 * last.closing_mps)
    seen = 1.2 - 0.8 * 29 * PERIOD_S
    assert last.distance_m == pytest.approx(seen - 0.5 * last.closing_mps, abs=1e-9)
    assert last.point[0] == pytest.approx(last.distance_m)


def test_parts_switch_off_alone():
    """No horizon: the task's point is the measured one; no feed-forward: f = 0; no growth: g = 0."""
    last = _approach(PredictionSettings(feedforward=False, horizon_s=0.0, growth_time_s=0.0), 0.8)[-1]
    assert last.point[0] == pytest.approx(1.2 - 0.8 * 29 * PERIOD_S)
    assert last.feedforward_mps == 0.0 and last.growth_m == 0.0 and last.closing_mps > 0.7


def test_a_path_through_the_control_point_needs_no_feed_forward():
    """Predicted to reach P within τ: the horizon's distance is the closest approach (f = 0), g still grows."""
    last = _approach(PredictionSettings(horizon_s=2.0, growth_time_s=0.3), 0.8)[-1]
    assert last.distance_m == pytest.approx(0.0, abs=1e-9)
    assert last.feedforward_mps == 0.0
    assert last.closing_mps == pytest.approx(0.8, abs=0.05) and last.growth_m == pytest.approx(0.3 * last.closing_mps)


def test_a_receding_person_gives_no_feed_forward():
    last = _approach(PredictionSettings(horizon_s=0.5, growth_time_s=0.3), -0.8)[-1]
    assert last.closing_mps == 0.0 and last.growth_m == 0.0
    assert last.point[0] == pytest.approx(1.2 + 0.8 * 29 * PERIOD_S)  # the path's nearest point is O


def test_a_person_closing_in_behind_a_surface_is_anticipated():
    """A hidden closest point O that stays put while the surface hiding it closes in at 0.8 m/s.

    Camera looking along +x, P at the origin, O on the ray 0.3 m beside P (the hidden space);
    the surface E walks along the ray towards P's depth. O alone gives no approach; with E the
    estimate follows the surface, and f and the closing speed are the surface's.
    """
    settings = PredictionSettings(horizon_s=0.25, growth_time_s=0.3)
    kin = _Kin({"cp": np.zeros(3)})
    hidden_only = EstimatedPrediction(settings, ["cp"])
    switched_off = EstimatedPrediction(replace(settings, hidden_surface=False), ["cp"])
    with_surface = EstimatedPrediction(settings, ["cp"])
    o = np.array([0.0, 0.3, 0.0])
    for k in range(30):
        t = k * PERIOD_S
        e = np.array([-1.2 + 0.8 * t, 0.3, 0.0])  # the person's surface on O's ray, nearing P's depth
        a = hidden_only.predict(t, {"cp": _Reading(o, occluded=True)}, kin)["cp"]  # type: ignore[arg-type]
        off = switched_off.predict(t, {"cp": _Reading(o, occluded=True, surface_point=e)}, kin)["cp"]  # type: ignore[arg-type]
        b = with_surface.predict(t, {"cp": _Reading(o, occluded=True, surface_point=e)}, kin)["cp"]  # type: ignore[arg-type]
        # switched off: the assumed point is followed, the surface ignored
        assert (off.closing_mps, off.feedforward_mps) == (a.closing_mps, a.feedforward_mps)
        assert off.distance_m == a.distance_m
    assert a.closing_mps == pytest.approx(0.0, abs=1e-6) and a.feedforward_mps == pytest.approx(0.0, abs=1e-6)
    closing_e = 0.8 * (-e[0]) / float(np.linalg.norm(e))  # -n_E^T v, v = (0.8, 0, 0)
    assert b.closing_mps == pytest.approx(closing_e, abs=0.05)
    seen = e + 0.25 * np.array([0.8, 0.0, 0.0])  # E's horizon point: the rate there is f
    assert b.feedforward_mps == pytest.approx(0.8 * (-seen[0]) / float(np.linalg.norm(seen)), abs=0.05)
    assert b.growth_m == pytest.approx(0.3 * b.closing_mps)
    np.testing.assert_allclose(b.point, o)  # O stays the nearer point: the distance is not raised
    assert with_surface.filters["cp"].velocity == pytest.approx([0.8, 0.0, 0.0], abs=0.05)


def test_nothing_in_range_gives_nothing_and_ends_the_track():
    pred = EstimatedPrediction(PredictionSettings(), ["cp"])
    kin = _Kin({"cp": np.zeros(3)})
    pred.predict(0.0, {"cp": _Reading(np.ones(3))}, kin)  # type: ignore[arg-type]
    assert pred.predict(PERIOD_S, {"cp": _Reading(None, in_range=False)}, kin)["cp"] is None  # type: ignore[arg-type]
    assert not pred.filters["cp"].tracking


def _walking_sphere(speed: float, start_x: float, step_s: float = 0.01) -> PersonTrack:
    """One sphere of radius 0.1 m walking along −x at ``speed`` for 4 s."""
    t = np.arange(0.0, 4.0 + step_s, step_s)
    centre = np.stack([start_x - speed * t, np.zeros_like(t), np.zeros_like(t)], axis=1)[:, None, :]
    return PersonTrack(step_s, centre, centre.copy(), np.array([0.1]), ("hand",))


@pytest.mark.parametrize("horizon_s", [0.0, 0.5])
def test_true_prediction_of_a_walking_sphere(horizon_s):
    """The truth: the distance the sphere will have after τ, closing at its speed, from any reading."""
    track = _walking_sphere(1.0, 2.0)
    settings = PredictionSettings(mode="truth", horizon_s=horizon_s, growth_time_s=0.3, range_m=5.0)
    pred = TruePrediction(settings, ["cp"], track, clock=lambda t: t)
    kin = _Kin({"cp": np.zeros(3)})
    p = pred.predict(1.0, {"cp": _Reading(None, in_range=False)}, kin)["cp"]  # type: ignore[arg-type]
    assert p is not None
    assert p.distance_m == pytest.approx(2.0 - 1.0 - horizon_s - 0.1, abs=1e-9)
    assert p.closing_mps == pytest.approx(1.0, abs=1e-9)
    assert p.growth_m == pytest.approx(0.3)
    # Past the sensing range: nothing.
    far = TruePrediction(PredictionSettings(mode="truth", range_m=0.3), ["cp"], track, clock=lambda t: t)
    assert far.predict(0.0, {"cp": _Reading(None, in_range=False)}, kin)["cp"] is None  # type: ignore[arg-type]


def test_true_prediction_keeps_a_nearer_sensed_point():
    track = _walking_sphere(1.0, 2.0)
    pred = TruePrediction(PredictionSettings(mode="truth", horizon_s=0.5), ["cp"], track, clock=lambda t: t)
    kin = _Kin({"cp": np.zeros(3)})
    near = np.array([0.0, 0.2, 0.0])
    p = pred.predict(0.0, {"cp": _Reading(near)}, kin)["cp"]  # type: ignore[arg-type]
    assert p is not None
    np.testing.assert_array_equal(p.point, near)


@pytest.mark.parametrize(
    "kwargs",
    [{"mode": "guess"}, {"horizon_s": -0.1}, {"growth_time_s": math.nan}, {"sample_s": 0.0}, {"range_m": 0.0}],
)
def test_bad_settings_are_refused(kwargs):
    with pytest.raises(ValueError):
        PredictionSettings(**kwargs)

r"""What the obstacle tasks are told about where the person will be: feed-forward, horizon, growth.

At every accepted sensing update each control point P gets, besides its closest obstacle point
O, a predicted motion of that point: its velocity v, estimated from the sensing stream
(:class:`EstimatedPrediction`, :mod:`compare.sensing.motion_estimate`) or the person's true
future (:class:`TruePrediction`, the upper bound a perfect predictor reaches). Three parts, each
switched on alone (:class:`PredictionSettings`), change what the shared obstacle task
(:class:`tpik.tasks.ObstacleDistanceTask`) holds, and so what every method receives:

* **horizon** τ (b): the task's point is the predicted obstacle point nearest to P over
  [t, t + τ]: with a constant-velocity estimate the point of the segment [O, O + τv] nearest to
  P; with the truth the nearest of the person's true closest points at t + s, s ∈ [0, τ] (step
  ``sample_s``), and O itself. τ = 0: the task's point is O.
* **feed-forward** (a): the rate at which the predicted distance ‖Q − P‖ falls with the
  person's motion (Q the task's point), :math:`f = \max(0, -n_Q^T v)`,
  :math:`n_Q = (Q - P)/\|Q - P\|` (the truth: a finite difference over ``sample_s``), added to
  the reference rate :math:`K(\sigma_s - \sigma) + f`: a person closing in at f no longer holds
  the distance f/K inside the threshold. With a horizon that the predicted path crosses at its
  nearest point, f = 0: the horizon's distance already is the closest approach.
* **growth** (c): every threshold moves out by :math:`g = v_c\,(T_r + T_s)`
  (``growth_time_s``), the human term :math:`v_h(T_r + T_s)` of ISO/TS 15066's protective
  separation distance with the closing speed of the closest point O,
  :math:`v_c = \max(0, -n_O^T v)`, as :math:`v_h` and the reaction and stopping times of
  ``[iso15066]``.

**Hidden space.** A depth reading whose closest point O is assumed from the space hidden behind
a measured surface (``occluded``) does not move as the person does: the hidden space already
counts as obstacle, so a person walking into it leaves O where it is. The estimate then follows
the measured surface point E nearest to P (``surface_point``), the person as seen; the task's
point is the nearer of the horizon points of O and E, and the closing speed and the feed-forward
are the faster of the two approaches: the person may close in behind the surface as fast as the
surface closes in. A measured closest point is its own surface point, so geometric sensing and
unoccluded readings are unchanged.

A control point with nothing in range gets nothing (its track ends). Nothing here reads the
scenario's keyframes except :class:`TruePrediction`, which exists to bound what prediction can do.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Literal, Protocol

import numpy as np

from compare.sensing.motion_estimate import MotionFilterSettings, PointMotionFilter
from compare.sensing.person_track import PersonTrack, capsule_margins
from robots import Kinematics

PredictionMode = Literal["estimated", "truth"]


@dataclass(frozen=True)
class PredictionSettings:
    """What is predicted and how (module docstring).

    Attributes:
        mode: ``"estimated"`` (from the sensing stream) or ``"truth"`` (the person's future).
        feedforward: Part (a): the rate the predicted distance falls, as rate feed-forward.
        horizon_s: Part (b): τ [s]; 0 = off.
        growth_time_s: Part (c): T_r + T_s [s]; 0 = off.
        sample_s: Step of the true future over the horizon and of its finite difference [s].
        range_m: Largest distance of a predicted point handed to a task [m] (the sensing range ρ).
        hidden_surface: Follow a point assumed from hidden space at the measured surface hiding
            it (module docstring); False: follow the assumed point itself.
        motion_filter: Noise model of the estimate.
    """

    mode: PredictionMode = "estimated"
    feedforward: bool = True
    horizon_s: float = 0.0
    growth_time_s: float = 0.0
    sample_s: float = 0.05
    range_m: float = math.inf
    hidden_surface: bool = True
    motion_filter: MotionFilterSettings = field(default_factory=MotionFilterSettings)

    def __post_init__(self) -> None:
        if self.mode not in ("estimated", "truth"):
            raise ValueError(f"mode must be 'estimated' or 'truth', got {self.mode!r}")
        for name in ("horizon_s", "growth_time_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f"{name} must be finite and >= 0, got {value}")
        if not (math.isfinite(self.sample_s) and self.sample_s > 0.0):
            raise ValueError(f"sample_s must be finite and > 0, got {self.sample_s}")
        if not self.range_m > 0.0:
            raise ValueError(f"range_m must be > 0, got {self.range_m}")


@dataclass(frozen=True)
class ObstaclePrediction:
    """What one control point's obstacle task is given at one sensing update.

    Attributes:
        point: The task's obstacle point [m] (the horizon's nearest point, or O). Shape (3,).
        distance_m: ‖point − P‖ at the update [m].
        closing_mps: v_c, the closing speed of the closest point O toward P, ≥ 0 [m/s].
        feedforward_mps: f handed to the task [m/s] (0 with the part off).
        growth_m: g handed to the task [m].
    """

    point: np.ndarray
    distance_m: float
    closing_mps: float
    feedforward_mps: float
    growth_m: float


class ReadingLike(Protocol):
    """A control point's sensing reading (:class:`compare.sensing.results.ObstacleReading`)."""

    closest_point: np.ndarray | None
    in_range: bool
    occluded: bool
    surface_point: np.ndarray | None


class Predictor(Protocol):
    """Anything that turns one accepted sensing update into the obstacle tasks' predictions."""

    settings: PredictionSettings

    def predict(
        self, t: float, readings: Mapping[str, ReadingLike], kin: Kinematics
    ) -> dict[str, ObstaclePrediction | None]:
        """Per control point, the prediction at loop time ``t`` [s] (None: nothing in range)."""
        ...


def _finish(
    settings: PredictionSettings, p: np.ndarray, point: np.ndarray, closing: float, falling: float
) -> ObstaclePrediction:
    """The prediction from the task's point, O's closing speed and the rate the point's distance falls."""
    closing = max(0.0, closing)
    return ObstaclePrediction(
        point=point,
        distance_m=float(np.linalg.norm(point - p)),
        closing_mps=closing,
        feedforward_mps=max(0.0, falling) if settings.feedforward else 0.0,
        growth_m=closing * settings.growth_time_s,
    )


def _approach_rate(p: np.ndarray, point: np.ndarray, v: np.ndarray) -> float:
    """:math:`-n^T v`, n the unit vector from P to ``point`` (0 when they coincide) [m/s]."""
    diff = point - p
    dist = float(np.linalg.norm(diff))
    return -float(diff @ v) / dist if dist > 1e-9 else 0.0


def nearest_on_path(p: np.ndarray, o: np.ndarray, v: np.ndarray, horizon_s: float) -> np.ndarray:
    r"""The point of the segment :math:`[O, O + \tau v]` nearest to P [m] (O when τ = 0 or v = 0)."""
    step = horizon_s * v
    length2 = float(step @ step)
    if length2 <= 0.0:
        return o.copy()
    s = min(1.0, max(0.0, float((p - o) @ step) / length2))
    return o + s * step


class EstimatedPrediction:
    """Predictions from the sensing stream alone: one motion filter per control point.

    Args:
        settings: :class:`PredictionSettings` (``mode = "estimated"``).
        control_points: The control point frames.
    """

    def __init__(self, settings: PredictionSettings, control_points: Sequence[str]) -> None:
        self.settings = settings
        self.filters = {cp: PointMotionFilter(settings.motion_filter) for cp in control_points}

    def predict(
        self, t: float, readings: Mapping[str, ReadingLike], kin: Kinematics
    ) -> dict[str, ObstaclePrediction | None]:
        """Per control point: filter update, then the horizon point, f and g (module docstring)."""
        out: dict[str, ObstaclePrediction | None] = {}
        s = self.settings
        for cp, motion in self.filters.items():
            r = readings.get(cp)
            if r is None or not r.in_range or r.closest_point is None:
                motion.reset()
                out[cp] = None
                continue
            o = np.asarray(r.closest_point, dtype=float)
            p = kin.frame_position(cp)
            # The filter follows the surface point E: the closest point itself when it is measured
            # (or nothing of the surface hiding it is known); the surface hiding it when it is
            # assumed, and the person may close in behind that surface as fast as it closes in.
            surface = r.surface_point if s.hidden_surface else None
            e = o if surface is None else np.asarray(surface, dtype=float)
            v = motion.update(t, e, bool(r.occluded) and surface is None)
            point = nearest_on_path(p, o, v, s.horizon_s)
            seen = nearest_on_path(p, e, v, s.horizon_s)
            if np.linalg.norm(seen - p) < np.linalg.norm(point - p):
                point = seen
            closing = max(_approach_rate(p, o, v), _approach_rate(p, e, v))
            falling = max(_approach_rate(p, point, v), _approach_rate(p, seen, v))
            out[cp] = _finish(s, p, point, closing, falling)
        return out


class TruePrediction:
    """Predictions from the person's true future: the bound of what prediction can do.

    Args:
        settings: :class:`PredictionSettings` (``mode = "truth"``).
        control_points: The control point frames.
        track: The person's capsules over the run.
        clock: The person's time at the loop time ``t``: ``clock(t)`` [s].
    """

    def __init__(
        self,
        settings: PredictionSettings,
        control_points: Sequence[str],
        track: PersonTrack,
        clock: Callable[[float], float],
    ) -> None:
        self.settings = settings
        self.control_points = tuple(control_points)
        self._track = track
        self._clock = clock
        n = int(round(settings.horizon_s / settings.sample_s))
        self._offsets = settings.sample_s * np.arange(n + 2)  # the horizon, and one step past it

    def predict(
        self, t: float, readings: Mapping[str, ReadingLike], kin: Kinematics
    ) -> dict[str, ObstaclePrediction | None]:
        """Per control point: the nearest true point over the horizon and its true closing speed."""
        s = self.settings
        pos = np.array([kin.frame_position(cp) for cp in self.control_points])  # (K, 3)
        a, b, radius = self._track.at(self._clock(t) + self._offsets)  # (J, G, 3)
        dist, normal = capsule_margins(np.broadcast_to(pos, (len(self._offsets), *pos.shape)), a, b, radius)
        nearest = dist.min(axis=2)  # (J, K): distance to the person at each instant
        which = dist.argmin(axis=2)
        horizon = nearest[:-1].min(axis=0)  # over [t, t + τ]
        later = nearest[1:].min(axis=0)  # over [t + h, t + τ + h]
        out: dict[str, ObstaclePrediction | None] = {}
        for k, cp in enumerate(self.control_points):
            r = readings.get(cp)
            sensed = None if r is None or not r.in_range else r.closest_point
            j = int(nearest[:-1, k].argmin())
            g = int(which[j, k])
            point = pos[k] - normal[j, k, g] * dist[j, k, g]
            if sensed is not None and float(np.linalg.norm(np.asarray(sensed) - pos[k])) <= float(horizon[k]):
                point = np.asarray(sensed, dtype=float)
            elif sensed is None and not horizon[k] <= s.range_m:
                out[cp] = None
                continue
            closing = -(float(nearest[1, k]) - float(nearest[0, k])) / s.sample_s
            falling = -(float(later[k]) - float(horizon[k])) / s.sample_s
            out[cp] = _finish(s, pos[k], point, closing, falling)
        return out

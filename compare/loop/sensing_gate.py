"""The sensing gate of the closed loop: when to sense, which updates to trust, when to stop (docs/design.md §4).

At the sensing rate (30 Hz) the gate asks the obstacle source for the closest obstacle point of
each control point and hands the readings to the obstacle tasks; between updates the latest
estimate is used. An update is checked when it arrives (:func:`sensing_problem`): a blind frame
(``DistanceResult.blind``: too few valid pixels, NaN or all-zero frames, no frame), a frame
older than ``stale_frame_periods`` sensing periods (frozen or delayed camera), or a reading that
is not finite. The gate is then *blind* from that same step on and logs why; the estimates of
the last good update are kept but not trusted. While the frame stamp does not advance, the
source is polled again at every control step (not only at the sensing rate), so a frozen frame
is caught within half a period plus one control period of being overdue. The older rule stays
as a second guard: no good update for ``max_sensing_age_s`` → blind.

A blind gate makes the loop command zero velocity (``stop_when_blind``, a safe stop).

With a predictor (``[prediction]``, :mod:`compare.sensing.prediction`) every good update also
goes through it, and each obstacle task receives the predicted point, feed-forward and growth
instead of the bare closest point.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping, Sequence
from typing import Protocol

import numpy as np

from compare.loop.settings import LoopSettings
from compare.sensing.prediction import Predictor
from robots import Kinematics
from tpik.tasks import ObstacleDistanceTask

log = logging.getLogger(__name__)


class ObstacleReadingLike(Protocol):
    """Closest obstacle of one control point (see :mod:`compare.sensing`)."""

    distance_m: float
    closest_point: np.ndarray | None
    in_range: bool


class DistanceResultLike(Protocol):
    """One sensing update: a reading per control point and whether the sensor is blind."""

    readings: Mapping[str, ObstacleReadingLike]
    blind: bool


class ObstacleSource(Protocol):
    """Anything that gives closest obstacle points for the control points."""

    def update(self, t: float, kin: Kinematics) -> DistanceResultLike:
        """Sense at time ``t`` [s] with the robot at ``kin.q``."""
        ...


def sensing_problem(result: DistanceResultLike, t: float, stale_after_s: float | None) -> str | None:
    """Why a sensing update must not be trusted, or None when it is usable.

    Args:
        result: The update.
        t: Loop time of the update [s] (the clock of ``result.stamp_s``).
        stale_after_s: Largest accepted age ``t - stamp_s`` of the frame [s]; None = no check.

    Returns:
        ``"blind frame ..."``, ``"stale frame ..."`` or ``"invalid reading ..."``, or None.
    """
    if result.blind:
        fraction = getattr(result, "valid_fraction", math.nan)
        return f"blind frame (valid fraction {fraction:.2f})"
    stamp = float(getattr(result, "stamp_s", math.nan))
    if stale_after_s is not None and math.isfinite(stamp) and t - stamp > stale_after_s + 1e-9:
        return f"stale frame (age {1e3 * (t - stamp):.0f} ms)"
    for name, r in result.readings.items():
        if not r.in_range:
            continue
        point = r.closest_point
        if not math.isfinite(r.distance_m) or point is None or not _all_finite(point):
            return f"invalid reading for {name}"
    return None


def _all_finite(point: np.ndarray) -> bool:
    """Every entry finite: a finite sum is the cheap test, the exact one only when it fails."""
    return math.isfinite(sum(np.ravel(point).tolist())) or bool(np.all(np.isfinite(point)))


class SensingGate:
    """Obstacle sensing of one run: rate, checks, the readings kept, blind or not (module docstring).

    Args:
        obstacles: The source; None = no sensing (the gate is never blind, nothing is measured).
        obstacle_tasks: The hierarchy's obstacle tasks; none = no sensing either.
        control_points: The frames whose measured distance is recorded.
        settings: The loop's rates and limits (``sensing_period_s``, ``stale_frame_periods``,
            ``max_sensing_age_s``).
        events: The run's event log (blind / recovered lines are appended).
        predictor: Prediction of the obstacles' motion; None = the tasks get the closest points.

    Attributes:
        blind: The latest update (or its absence) is not to be trusted: stop.
        reason: Why it is blind ("" when it is not).
        measured: Measured distance of each control point (in ``control_points`` order) of the
            last good update [m] (inf: none).
        source: Per control point, (reading assumed from hidden space, camera name) of that update.
        predicted: Per control point, (predicted distance [m], predicted closing speed [m/s]) of
            that update; (inf, 0) without a predictor or a prediction.

    The three are tuples, replaced (never changed in place) by a good update: a reader may keep
    a reference as the value of its step.
    """

    def __init__(
        self,
        obstacles: ObstacleSource | None,
        obstacle_tasks: Sequence[ObstacleDistanceTask],
        control_points: Sequence[str],
        settings: LoopSettings,
        events: list[str],
        predictor: Predictor | None = None,
    ) -> None:
        self.active = obstacles is not None and bool(obstacle_tasks)
        self._predictor = predictor
        self._obstacles = obstacles
        self._tasks = tuple(obstacle_tasks)
        self._cps = tuple(control_points)
        self._period_s = settings.sensing_period_s
        self._max_age_s = settings.max_sensing_age_s
        periods = settings.stale_frame_periods
        self._stale_after_s = None if periods is None else periods * settings.sensing_period_s
        self._events = events
        self.blind = self.active
        self.reason = ""
        self.measured: tuple[float, ...] = (math.inf,) * len(self._cps)
        self.source: tuple[tuple[bool, str], ...] = ((False, ""),) * len(self._cps)
        self.predicted: tuple[tuple[float, float], ...] = ((math.inf, 0.0),) * len(self._cps)
        self._next_t = -math.inf
        self._last_good_t = -math.inf
        self._last_stamp = math.nan
        self._repoll = False
        self._problem: str | None = None  # why the latest update was not usable (None: it was)
        self._was_blind = False

    def step(self, t: float, kin: Kinematics) -> None:
        """Sense when due (or when the last frame did not advance), then judge the sensing at ``t`` [s]."""
        if not self.active:
            return
        if t + 1e-9 >= self._next_t or self._repoll:
            self._sense(t, kin)
        self._judge(t)

    def _sense(self, t: float, kin: Kinematics) -> None:
        """One update of the source; a usable one replaces the readings."""
        if t + 1e-9 >= self._next_t:
            self._next_t = t + self._period_s if self._next_t < 0 else self._next_t + self._period_s
        assert self._obstacles is not None
        result = self._obstacles.update(t, kin)
        stamp = float(getattr(result, "stamp_s", math.nan))
        self._repoll = math.isfinite(stamp) and stamp == self._last_stamp  # frame did not advance: look again
        self._last_stamp = stamp
        self._problem = sensing_problem(result, t, self._stale_after_s)
        if self._problem is None:
            self._last_good_t = t
            self._accept(result, t, kin)

    def _accept(self, result: DistanceResultLike, t: float, kin: Kinematics) -> None:
        """Hand a good update (through the predictor, if any) to the obstacle tasks and keep its readings."""
        if self._predictor is not None:
            self._hand_predictions(result, t, kin)
        else:
            for task in self._tasks:
                r = result.readings.get(task.frame)
                task.set_obstacle(r.closest_point if r is not None and r.in_range else None)
        measured: list[float] = []
        source: list[tuple[bool, str]] = []
        for cp in self._cps:
            r = result.readings.get(cp)
            if r is not None and r.in_range:
                measured.append(r.distance_m)
                # What the reading is: assumed from hidden space (occluded) or measured, and by which camera.
                source.append((bool(getattr(r, "occluded", False)), getattr(r, "camera", None) or ""))
            else:
                measured.append(math.inf)
                source.append((False, ""))
        self.measured, self.source = tuple(measured), tuple(source)

    def _hand_predictions(self, result: DistanceResultLike, t: float, kin: Kinematics) -> None:
        assert self._predictor is not None
        predictions = self._predictor.predict(t, result.readings, kin)  # type: ignore[arg-type]
        for task in self._tasks:
            p = predictions.get(task.frame)
            if p is None:
                task.set_obstacle(None)
            else:
                task.set_obstacle(p.point, p.feedforward_mps, p.growth_m)
        self.predicted = tuple(
            (math.inf, 0.0) if p is None else (p.distance_m, p.closing_mps) for p in map(predictions.get, self._cps)
        )

    def _judge(self, t: float) -> None:
        """Blind or not at ``t`` [s]; a change (or a new kind of problem) is logged."""
        if self._problem is None and not self._was_blind and t - self._last_good_t <= self._max_age_s:
            self.blind, self.reason = False, ""  # the common case: good, and good before
            return
        if self._problem is not None:
            reason_now = self._problem
        elif t - self._last_good_t > self._max_age_s:
            reason_now = f"no good sensing update (for {1e3 * (t - self._last_good_t):.0f} ms)"
        else:
            reason_now = ""
        blind = bool(reason_now)
        self.blind = blind
        if blind != self._was_blind or (blind and reason_now.split(" (")[0] != self.reason.split(" (")[0]):
            what = f"sensing blind or stale: {reason_now}: safe stop" if blind else "sensing recovered"
            self._events.append(f"t={t:.3f} s: {what}")
            log.warning(self._events[-1])
            self._was_blind = blind
        self.reason = reason_now

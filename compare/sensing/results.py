"""What a sensing update returns, in depth and in geometric mode alike."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class ObstacleReading:
    """Closest obstacle point of one control point.

    Attributes:
        distance_m: Distance from the control point to its closest obstacle point [m]; ``inf``
            when nothing is in range.
        closest_point: Closest obstacle point O in the base frame [m], shape (3,); ``None`` when
            nothing is in range.
        in_range: Whether an obstacle was found within the surveillance distance ρ.
        occluded: The closest point was not measured but assumed: it lies in space hidden behind
            a measured surface (occluded space counts as obstacle, Flacco et al.), from every
            camera (several cameras: ``compare.sensing.fusion``). False for a measured point,
            for geometric sensing and when nothing is in range.
        camera: Name of the camera whose pixel gave the closest point (measured, or the one
            behind whose surface it is hidden); None in geometric mode or when nothing is in range.
        surface_point: For an ``occluded`` reading, the measured surface point nearest to the
            control point (base frame [m], shape (3,)): what is seen of the obstacle that hides
            the closest point. None otherwise (the closest point is itself measured).
    """

    distance_m: float
    closest_point: np.ndarray | None
    in_range: bool
    occluded: bool = False
    camera: str | None = None
    surface_point: np.ndarray | None = None

    @classmethod
    def nothing(cls) -> ObstacleReading:
        """The reading "no obstacle within ρ" (one shared instance: a reading is immutable)."""
        if cls is ObstacleReading:
            return _NOTHING
        return cls(math.inf, None, False)


_NOTHING = ObstacleReading(math.inf, None, False)


@dataclass(frozen=True)
class DistanceResult:
    """One sensing update: a reading per control point and the sensor's health.

    Attributes:
        readings: Reading per control point frame name (``"link_4"``, ``"link_6"``, ``"link_7"``).
        valid_fraction: Fraction of pixels of the raw depth frame with a return, in [0, 1]
            (1.0 in geometric mode).
        blind: ``valid_fraction`` is below the configured threshold (or no frame arrived): the
            readings must not be trusted and the controller should stop safely.
        stamp_s: Capture time of the frame (or time of the geometric query) [s]; NaN if unknown.
        pixels_visited: Valid pixels examined over all surveillance regions (0 in geometric mode).
        out_of_view: Control points whose surveillance cube lies entirely outside the camera's
            view or range (of every camera): their "nothing in range" means "not observed".
        cameras: With several cameras, each camera's own result (before fusion), in
            ``[[sensor.cameras]]`` order; empty otherwise. With several cameras
            ``valid_fraction`` is the smallest camera's, ``blind`` is any camera's, and
            ``stamp_s`` the oldest frame's.
    """

    readings: dict[str, ObstacleReading]
    valid_fraction: float
    blind: bool
    stamp_s: float = math.nan
    pixels_visited: int = 0
    out_of_view: tuple[str, ...] = field(default_factory=tuple)
    cameras: tuple[DistanceResult, ...] = field(default_factory=tuple)

    def distances(self) -> dict[str, float]:
        """Distance per control point [m] (``inf`` when nothing is in range)."""
        return {name: r.distance_m for name, r in self.readings.items()}

    def occluded(self) -> dict[str, bool]:
        """Per control point: the closest point was assumed from hidden space, not measured."""
        return {name: r.occluded for name, r in self.readings.items()}

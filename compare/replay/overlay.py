"""What a video panel shows besides the 3D scene, and how it is drawn (MuJoCo's 2D overlay calls).

Per panel: the method and the time, the step's status (a coloured badge), the set tasks in the
solver's active set, and one bar per control point: its measured obstacle distance against the
physical, safety and activation thresholds of its obstacle task (ticks), the true distance as a
white tick. Colours by margin (:func:`margin_colour`): green clear of the activation threshold,
amber inside the activation zone, red below the safety threshold, dark red below the physical one.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numpy as np

from compare.analysis.metrics import VIOLATION_TOLERANCE
from compare.replay.run_data import MethodRun, ReplayRun

RGB = tuple[float, float, float]

CLEAR: RGB = (0.20, 0.72, 0.30)
ACTIVATION: RGB = (1.00, 0.62, 0.05)
SAFETY: RGB = (0.90, 0.12, 0.10)
PHYSICAL: RGB = (0.45, 0.00, 0.00)
UNKNOWN: RGB = (0.55, 0.55, 0.55)
STATUS_COLOURS: dict[str, RGB] = {"ok": CLEAR, "degraded": ACTIVATION, "failed": SAFETY, "ended": UNKNOWN}


@dataclass(frozen=True)
class DistanceBar:
    """One control point's distance and the thresholds of its obstacle task [m] (NaN: none)."""

    frame: str
    measured_m: float
    true_m: float
    physical_m: float
    safety_m: float
    activation_m: float


@dataclass(frozen=True)
class PanelInfo:
    """The overlay of one method's panel at one instant.

    Attributes:
        method: Method key.
        t: Time [s].
        status: ``ok`` | ``degraded`` | ``failed`` (the step's), or ``ended`` past the method's last step.
        active: Set tasks in the active set at that step.
        distances: One bar per control point.
    """

    method: str
    t: float
    status: str
    active: tuple[str, ...]
    distances: tuple[DistanceBar, ...]


def margin_colour(distance_m: float, physical_m: float, safety_m: float, activation_m: float) -> RGB:
    """Colour of a distance by the zone it is in (module docstring); grey when unknown or out of range.

    A threshold is crossed as the metrics count it: by more than
    :data:`compare.analysis.metrics.VIOLATION_TOLERANCE` (an active task holds σ at its threshold).
    """
    if not math.isfinite(distance_m):
        return UNKNOWN
    if math.isfinite(physical_m) and distance_m < physical_m - VIOLATION_TOLERANCE:
        return PHYSICAL
    if math.isfinite(safety_m) and distance_m < safety_m - VIOLATION_TOLERANCE:
        return SAFETY
    if math.isfinite(activation_m) and distance_m < activation_m:
        return ACTIVATION
    return CLEAR


class PanelSource:
    """Builds :class:`PanelInfo` of one method quickly (the table's columns as arrays, read once).

    Args:
        run: The loaded run (thresholds, control points).
        method: The method's recorded run.
    """

    def __init__(self, run: ReplayRun, method: MethodRun) -> None:
        self.method = method
        self._end = float(method.t[-1]) + run.config.scenario.dt
        self._tasks = tuple(t.name for t in run.set_tasks if f"active:{t.name}" in method.steps.columns)
        self._active = (
            np.column_stack([method.steps[f"active:{n}"].fillna(False).to_numpy(dtype=bool) for n in self._tasks])
            if self._tasks
            else np.zeros((len(method.t), 0), dtype=bool)
        )
        self._status = method.steps["status"].astype(str).to_numpy() if "status" in method.steps.columns else None
        thresholds = run.obstacle_thresholds()
        self._frames = run.control_points
        self._limits = []
        for frame in self._frames:
            th = thresholds.get(frame)
            if th is None:
                self._limits.append((math.nan, math.nan, math.nan))
            else:
                self._limits.append((th.physical_lower, th.safety_lower, th.safety_lower + th.activation_margin))
        self._measured = [method.column(f"dist_meas:{f}") for f in self._frames]
        self._true = [method.column(f"dist_true:{f}") for f in self._frames]

    def info(self, row: int, t: float) -> PanelInfo:
        """The overlay at step ``row`` shown at time ``t`` [s]."""
        status = "ended" if t >= self._end + 1e-9 else (str(self._status[row]) if self._status is not None else "ok")
        active = tuple(n for n, on in zip(self._tasks, self._active[row], strict=True) if on)
        bars = tuple(
            DistanceBar(frame, float(meas[row]), float(true[row]), *limits)
            for frame, meas, true, limits in zip(self._frames, self._measured, self._true, self._limits, strict=True)
        )
        return PanelInfo(self.method.name, t, status, active, bars)


@dataclass(frozen=True)
class OverlayStyle:
    """Sizes of the overlay [px] and the distance shown by a full bar [m]."""

    row_px: int
    badge_px: tuple[int, int]
    full_bar_m: float
    label_px: int = 0
    """Width of a bar's label (frame and distance); 0: 42 % of the panel."""
    max_active_lines: int = 4

    def strip_px(self, bars: int) -> int:
        """Height of the strip under the 3D view that holds ``bars`` distance bars [px]."""
        return 8 + bars * (self.row_px + 4) if bars else 0

    @classmethod
    def for_height(cls, height_px: int, full_bar_m: float, label_px: int = 0) -> OverlayStyle:
        """Sizes proportional to the frame height (720 px: 24 px rows)."""
        row = max(12, round(height_px / 30))
        return cls(row, (max(40, round(height_px / 8)), row + 4), full_bar_m, label_px)


def label_width_px(ctx: mujoco.MjrContext, frames: tuple[str, ...]) -> int:
    """Width of the widest bar label (``frame  0.000 m``) in the context's normal font [px]."""

    def width(text: str) -> int:
        return int(sum(ctx.charWidth[ord(c)] for c in text if ord(c) < len(ctx.charWidth)))

    return max((width(f) for f in frames), default=0) + width("0.000 m") + ctx.charHeight


def draw_panel(ctx: mujoco.MjrContext, rect: mujoco.MjrRect, info: PanelInfo, style: OverlayStyle) -> None:
    """Draw ``info`` into the panel ``rect`` (GL pixels, origin bottom-left).

    The 3D view is already rendered above the bottom strip (:meth:`OverlayStyle.strip_px`); the
    text goes over it, the distance bars into the strip.
    """
    font = mujoco.mjtFont.mjFONT_NORMAL
    strip = style.strip_px(len(info.distances))
    if strip:
        mujoco.mjr_rectangle(mujoco.MjrRect(rect.left, rect.bottom, rect.width, strip), 0.08, 0.08, 0.1, 1.0)
    lines = list(info.active[: style.max_active_lines])
    if len(info.active) > style.max_active_lines:
        lines.append(f"+{len(info.active) - style.max_active_lines} more")
    left = "\n".join(["method", "time", "active", *[""] * max(0, len(lines) - 1)])
    right = "\n".join([info.method, f"{info.t:6.2f} s", *(lines or ["none"])])
    mujoco.mjr_overlay(font, mujoco.mjtGridPos.mjGRID_TOPLEFT, rect, left, right, ctx)
    bw, bh = style.badge_px
    badge = mujoco.MjrRect(rect.left + rect.width - bw - 6, rect.bottom + rect.height - bh - 6, bw, bh)
    r, g, b = STATUS_COLOURS.get(info.status, UNKNOWN)
    mujoco.mjr_label(badge, font, info.status, r, g, b, 0.9, 1.0, 1.0, 1.0, ctx)
    for i, bar in enumerate(reversed(info.distances)):
        _draw_bar(ctx, rect, rect.bottom + 6 + i * (style.row_px + 4), bar, style)


def _draw_bar(ctx: mujoco.MjrContext, panel: mujoco.MjrRect, y: int, bar: DistanceBar, style: OverlayStyle) -> None:
    """One control point's row: a label, then the bar with its threshold ticks."""
    h = style.row_px
    label_w = style.label_px or round(0.42 * panel.width)
    x0 = panel.left + 6
    text = f"{bar.measured_m:.3f} m" if math.isfinite(bar.measured_m) else "-"
    mujoco.mjr_overlay(
        mujoco.mjtFont.mjFONT_NORMAL,
        mujoco.mjtGridPos.mjGRID_LEFT,
        mujoco.MjrRect(x0, y, label_w, h),
        text,
        bar.frame,
        ctx,
    )
    bx, bw = x0 + label_w + 4, max(20, panel.width - label_w - 16)
    mujoco.mjr_rectangle(mujoco.MjrRect(bx, y, bw, h), 0.1, 0.1, 0.12, 0.75)

    def x_of(d: float) -> int:
        return bx + round(bw * min(max(d, 0.0), style.full_bar_m) / style.full_bar_m)

    if math.isfinite(bar.measured_m):
        colour = margin_colour(bar.measured_m, bar.physical_m, bar.safety_m, bar.activation_m)
        width = x_of(bar.measured_m) - bx
        if width > 0:
            mujoco.mjr_rectangle(mujoco.MjrRect(bx, y + 3, width, h - 6), *colour, 1.0)
    for d, colour in ((bar.physical_m, PHYSICAL), (bar.safety_m, SAFETY), (bar.activation_m, ACTIVATION)):
        if math.isfinite(d):
            mujoco.mjr_rectangle(mujoco.MjrRect(x_of(d) - 1, y, 3, h), *colour, 1.0)
    if math.isfinite(bar.true_m):
        mujoco.mjr_rectangle(mujoco.MjrRect(x_of(bar.true_m) - 1, y + 1, 2, h - 2), 1.0, 1.0, 1.0, 1.0)

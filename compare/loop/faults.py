r"""Fault injection from config (``[faults]``), identical for every method, as wrappers.

The closed loop (:func:`compare.loop.closed_loop.run_loop`) stays one loop: faults are injected by wrapping
what it talks to, and every method of a run gets wrappers built from the same specs and seeds,
so each sees the same faults at the same times.

===================== =========================== ===============================================
kind                  wrapper                     what the controller receives in the window
===================== =========================== ===============================================
``depth_nan``         :class:`FaultyRobotIO`      frames with ``fraction`` of the pixels NaN
``depth_zero``        :class:`FaultyRobotIO`      frames with ``fraction`` of the pixels 0
``depth_dropout``     :class:`FaultyRobotIO`      a burst of pixel dropout (``fraction`` → 0)
``depth_frozen``      :class:`FaultyRobotIO`      the last frame before the window, again and
                                                  again (stamp and content frozen)
``depth_delay``       :class:`FaultyRobotIO`      frames ``delay_s`` old (a late stream)
``joint_noise``       :class:`FaultyRobotIO`      q + N(0, ``std_rad``²), q̇ + N(0, ``std_rad_s``²)
``solver_fail``       :class:`FaultySolver`       a FAILED step (zero velocity, message)
``solver_timeout``    :class:`FaultySolver`       the solve takes ``delay_s`` more than it did;
                                                  beyond ``deadline_s`` it is FAILED ("timeout")
===================== =========================== ===============================================

In ``geometric`` sensing mode there are no frames: :class:`FaultyObstacleSource` gives the loop
what the depth pipeline would make of them: NaN, zero or dropout of a ``fraction`` ≥
1 − ``sensor.blind_fraction`` → a blind update (a smaller fraction only lowers its valid
fraction); frozen → the last update before the window, stamp included; delay → the update of
``delay_s`` ago.

Expected reactions (measured by :meth:`FaultInjector.summarize`, checked by
``tests/compare/loop/test_faults.py``):

* blind or invalid frames → zero velocity at the sensing update that receives the first one,
  logged (``reason`` column, ``events``);
* frozen frames and delays > ``stale_frame_periods`` (1.5) sensing periods → zero velocity once
  the frame is older than 1.5 periods: at most :math:`0.5\,T + \Delta t` after the first frame that
  should have been new (the loop polls every control step while the stamp does not advance);
  delays ≤ 1.5 periods are tolerated (the estimate is used, ISO/TS 15066's reaction time covers it);
* solver failure or timeout → the loop's fallback in the same step;
* joint noise → no reaction (tolerated); the guard still keeps every command finite and in limits.

A fault's *reaction latency* is the time from the first step at which the controller received
faulty data to the first step with the reaction; ``reaction_latency_from_start_s`` counts from the
configured start instead.
"""

from __future__ import annotations

import math
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, cast

import numpy as np
import pandas as pd

from compare.config import FaultsConfig, FaultSpec
from compare.loop.closed_loop import DistanceResultLike, ObstacleSource
from compare.loop.robot_io import JointReading, RobotIO
from compare.sensing.frames import DepthFrame
from compare.sensing.results import DistanceResult, ObstacleReading
from robots import Kinematics
from tpik.hierarchy import Hierarchy
from tpik.step_result import IkSolver, StepResult, failed

FRAME_KINDS = ("depth_nan", "depth_zero", "depth_dropout", "depth_frozen", "depth_delay")
"""Faults of the depth stream: the expected reaction is a safe stop."""
PIXEL_KINDS = ("depth_nan", "depth_zero", "depth_dropout")
SOLVER_KINDS = ("solver_fail", "solver_timeout")
"""Faults of the solver: the expected reaction is the loop's fallback."""
JOINT_KINDS = ("joint_noise",)
"""Faults of the joint state: tolerated (no reaction expected)."""


@dataclass(frozen=True)
class FaultWindow:
    """One fault spec resolved for a run: its index, times after ``time_scale``, and its spec.

    Attributes:
        index: Position in ``[[faults.inject]]``.
        spec: The configured fault.
        start_s: Start on the loop's clock [s].
        end_s: End (exclusive) [s].
    """

    index: int
    spec: FaultSpec
    start_s: float
    end_s: float

    @property
    def kind(self) -> str:
        """The fault kind."""
        return self.spec.kind

    def active(self, t: float) -> bool:
        """Whether the fault is on at loop time ``t`` [s]."""
        return self.start_s - 1e-9 <= t < self.end_s - 1e-9


@dataclass
class FaultLog:
    """When each fault actually altered what the controller received.

    Attributes:
        hits: Loop times [s] per fault index (one entry per control step at most).
        notes: Free-form details per fault index (e.g. the timeout durations).
    """

    hits: dict[int, list[float]] = field(default_factory=dict)
    notes: dict[int, list[str]] = field(default_factory=dict)

    def record(self, index: int, t: float) -> None:
        """Note that fault ``index`` altered data at loop time ``t`` [s]."""
        times = self.hits.setdefault(index, [])
        if not times or abs(times[-1] - t) > 1e-9:
            times.append(float(t))


class FaultInjector:
    """Builds the wrappers of one run and measures the reactions afterwards.

    Args:
        config: The ``[faults]`` section.
        seed: Scenario seed (``scenario.seed``); the draws use ``seed + seed_offset`` and the
            fault's index, so every method sees the same pixels and the same noise.
        time_scale: ``scenario.time_scale`` (multiplies start and end times).
        clock: The backend's clock [s]; loop time is ``clock() - clock()`` at construction.
        blind_fraction: ``sensor.blind_fraction`` (geometric-mode emulation of pixel faults).
        control_period_s: The loop period [s] (default deadline of ``solver_timeout``).
    """

    def __init__(
        self,
        config: FaultsConfig,
        seed: int,
        time_scale: float,
        clock: Callable[[], float],
        blind_fraction: float = 0.3,
        control_period_s: float = 0.01,
    ) -> None:
        self.windows = [
            FaultWindow(i, spec, spec.start_s * time_scale, spec.end_s * time_scale)
            for i, spec in enumerate(config.inject)
        ]
        self._seed = int(seed) + int(config.seed_offset)
        self._clock = clock
        self._t0 = clock()
        self.blind_fraction = float(blind_fraction)
        self.control_period_s = float(control_period_s)
        self.log = FaultLog()

    @property
    def enabled(self) -> bool:
        """Whether any fault is configured."""
        return bool(self.windows)

    def now(self) -> float:
        """Loop time [s]."""
        return self._clock() - self._t0

    def rng(self, window: FaultWindow, camera: int = 0) -> np.random.Generator:
        """The random stream of one fault (same for every method); camera > 0: that camera's own."""
        key = [self._seed, window.index, 15066] + ([camera] if camera else [])
        return np.random.default_rng(key)

    def of_kind(self, *kinds: str) -> list[FaultWindow]:
        """The windows of the given kinds, in config order."""
        return [w for w in self.windows if w.kind in kinds]

    # -- wrappers ---------------------------------------------------------------------------
    def wrap_io(self, io: RobotIO) -> RobotIO:
        """``io`` with frame and joint faults (``io`` itself when there are none)."""
        if not self.of_kind(*FRAME_KINDS, *JOINT_KINDS):
            return io
        return FaultyRobotIO(io, self)

    def wrap_obstacles(self, source: ObstacleSource) -> ObstacleSource:
        """A geometric-mode source with frame faults emulated (``source`` when there are none)."""
        if not self.of_kind(*FRAME_KINDS):
            return source
        return FaultyObstacleSource(source, self)

    def wrap_solver(self, solver: IkSolver) -> IkSolver:
        """``solver`` with solver faults (``solver`` itself when there are none)."""
        if not self.of_kind(*SOLVER_KINDS):
            return solver
        return FaultySolver(solver, self)

    # -- results ----------------------------------------------------------------------------
    def annotate(self, steps: pd.DataFrame) -> pd.DataFrame:
        """``steps`` with a boolean column ``fault:<kind>`` per configured kind (data altered that step)."""
        if not self.windows or steps.empty:
            return steps
        t = steps["t"].to_numpy(dtype=float)
        extra: dict[str, np.ndarray] = {}
        for w in self.windows:
            col = extra.setdefault(f"fault:{w.kind}", np.zeros(len(t), dtype=bool))
            hits = np.asarray(self.log.hits.get(w.index, []), dtype=float)
            if hits.size:
                idx = np.clip(np.searchsorted(t, hits - 1e-9), 0, len(t) - 1)
                col[idx[np.abs(t[idx] - hits) < 1e-6]] = True
        return steps.assign(**extra)

    def summarize(self, steps: pd.DataFrame, sensing_period_s: float) -> dict[str, Any]:
        """Per fault kind: what was injected and how the loop reacted.

        Args:
            steps: The run's per-step table (``t``, ``qdot_*``, ``blind``, ``fallback``, ``reason``).
            sensing_period_s: Sensing period [s] (a stop must follow a frame fault within the
                faulty stretch plus ``max`` 2 periods to count as its reaction).

        Returns:
            ``{kind: {"windows", "injected_steps", "first_injected_t_s", "reaction",
            "reacted_windows", "reaction_latency_s_max", "reaction_latency_from_start_s_max",
            "stopped_steps", "fallback_steps", "moving_steps_while_faulty"}}``. ``reaction`` is
            ``safe_stop``, ``fallback``, ``tolerated`` (joint noise, short delays), ``none`` (a
            fault that should have been reacted to was not) or ``not_triggered`` (no data was
            altered, e.g. a window after the end of the run).
        """
        if not self.windows or steps.empty:
            return {}
        t = steps["t"].to_numpy(dtype=float)
        qcols = sorted((c for c in steps.columns if c.startswith("qdot_")), key=lambda c: int(c.split("_")[1]))
        moving = np.any(steps[qcols].to_numpy(dtype=float) != 0.0, axis=1) if qcols else np.zeros(len(t), bool)
        reason = steps["reason"].astype(str).to_numpy() if "reason" in steps.columns else np.full(len(t), "")
        stop = np.array(["sensing:" in r for r in reason]) & ~moving
        fallback = steps["fallback"].to_numpy(dtype=bool) if "fallback" in steps.columns else np.zeros(len(t), bool)
        per_window: dict[str, list[dict[str, Any]]] = {}
        for w in self.windows:
            per_window.setdefault(w.kind, []).append(
                self._window_reaction(w, t, stop, fallback, moving, sensing_period_s)
            )
        return {kind: _aggregate(rows) for kind, rows in per_window.items()}

    def _window_reaction(
        self,
        w: FaultWindow,
        t: np.ndarray,
        stop: np.ndarray,
        fallback: np.ndarray,
        moving: np.ndarray,
        period_s: float,
    ) -> dict[str, Any]:
        hits = self.log.hits.get(w.index, [])
        row: dict[str, Any] = {
            "injected_steps": len(hits),
            "first_injected_t_s": _round(hits[0]) if hits else None,
            "reaction": "not_triggered",
            "latency": None,
            "latency_from_start": None,
            "stopped_steps": 0,
            "fallback_steps": 0,
            "moving_steps_while_faulty": 0,
        }
        if not hits:
            return row
        first, last = hits[0], hits[-1]
        inside = (t >= first - 1e-9) & (t <= last + 1e-9)
        if w.kind in SOLVER_KINDS:
            hit_idx = np.searchsorted(t, np.asarray(hits) - 1e-9)
            hit_idx = hit_idx[hit_idx < len(t)]
            reacted = hit_idx[fallback[hit_idx]]
            row["fallback_steps"] = int(reacted.size)
            if reacted.size:
                row["reaction"] = "fallback" if reacted.size == hit_idx.size else "none"
                row["latency"] = _round(float(t[reacted[0]] - first))
                row["latency_from_start"] = _round(float(t[reacted[0]] - w.start_s))
            else:
                row["reaction"] = "none"
            return row
        if w.kind in JOINT_KINDS:
            row["reaction"] = "tolerated"
            return row
        # Frame faults: the first safe stop at or after the first faulty update.
        window = (t >= first - 1e-9) & (t <= last + 2.0 * period_s + 1e-9)
        idx = np.flatnonzero(window & stop)
        row["stopped_steps"] = int(np.count_nonzero(inside & stop))
        if idx.size:
            t_r = float(t[idx[0]])
            row["reaction"] = "safe_stop"
            row["latency"] = _round(t_r - first)
            row["latency_from_start"] = _round(t_r - w.start_s)
            row["moving_steps_while_faulty"] = int(np.count_nonzero((t >= t_r) & (t <= last + 1e-9) & moving))
        elif w.kind == "depth_delay" or (w.kind in PIXEL_KINDS and w.spec.fraction < 1.0):
            row["reaction"] = "tolerated"  # a short delay or a partial loss the sensing copes with
        else:
            row["reaction"] = "none"
        return row


def _round(x: float) -> float:
    """Times on the control grid, without the float noise of accumulated periods (µs resolution)."""
    return round(float(x), 6) + 0.0


def _aggregate(rows: list[dict[str, Any]]) -> dict[str, Any]:
    reactions = {r["reaction"] for r in rows if r["reaction"] != "not_triggered"}
    if not reactions:
        reaction = "not_triggered"
    elif "none" in reactions:
        reaction = "none"
    else:
        reaction = "/".join(sorted(reactions))
    latencies = [r["latency"] for r in rows if r["latency"] is not None]
    from_start = [r["latency_from_start"] for r in rows if r["latency_from_start"] is not None]
    firsts = [r["first_injected_t_s"] for r in rows if r["first_injected_t_s"] is not None]
    return {
        "windows": len(rows),
        "injected_steps": int(sum(r["injected_steps"] for r in rows)),
        "first_injected_t_s": min(firsts) if firsts else None,
        "reaction": reaction,
        "reacted_windows": int(sum(r["reaction"] in ("safe_stop", "fallback") for r in rows)),
        "reaction_latency_s_max": max(latencies) if latencies else None,
        "reaction_latency_from_start_s_max": max(from_start) if from_start else None,
        "stopped_steps": int(sum(r["stopped_steps"] for r in rows)),
        "fallback_steps": int(sum(r["fallback_steps"] for r in rows)),
        "moving_steps_while_faulty": int(sum(r["moving_steps_while_faulty"] for r in rows)),
    }


def unsafe_commands(steps: pd.DataFrame, v_max: np.ndarray) -> int:
    """Steps whose sent command (``qdot_*``) is not finite or exceeds the velocity limits (always 0)."""
    qcols = sorted((c for c in steps.columns if c.startswith("qdot_")), key=lambda c: int(c.split("_")[1]))
    if not qcols:
        return 0
    qdot = steps[qcols].to_numpy(dtype=float)
    bad = ~np.all(np.isfinite(qdot), axis=1)
    with np.errstate(invalid="ignore"):
        bad |= np.any(np.abs(qdot) > np.asarray(v_max)[None, : len(qcols)] * (1.0 + 1e-6) + 1e-9, axis=1)
    return int(np.count_nonzero(bad))


# ----------------------------------------------------------------------------------- RobotIO side


class FaultyRobotIO(RobotIO):
    """A :class:`RobotIO` whose depth frames and joint readings carry the configured faults.

    With several cameras (:meth:`read_depth_frames`) each camera's stream carries the frame
    faults whose ``camera`` is its index or unset (every camera), with its own pixel draws.

    Args:
        io: The real backend.
        injector: The run's injector (windows, random streams, log).
    """

    def __init__(self, io: RobotIO, injector: FaultInjector) -> None:
        self._io = io
        self._inj = injector
        self.dt = io.dt
        self.nq = io.nq
        self._frame_windows = injector.of_kind(*FRAME_KINDS)
        self._joint_windows = injector.of_kind(*JOINT_KINDS)
        self._rngs = {w.index: injector.rng(w) for w in injector.windows}
        self._streams: dict[int, _FrameStream] = {}

    def __getattr__(self, name: str) -> Any:  # model, data, ... of the wrapped backend
        return getattr(self._io, name)

    def now(self) -> float:
        """The backend's clock [s]."""
        return self._io.now()

    def read_joints(self) -> JointReading | None:
        """The backend's reading, plus noise while a ``joint_noise`` window is on."""
        reading = self._io.read_joints()
        if reading is None or not self._joint_windows:
            return reading
        t = self._inj.now()
        q, qdot = reading.q, reading.qdot
        for w in self._joint_windows:
            if w.active(t):
                rng = self._rngs[w.index]
                q = q + rng.normal(0.0, w.spec.std_rad, q.shape)
                if w.spec.std_rad_s > 0.0:
                    qdot = qdot + rng.normal(0.0, w.spec.std_rad_s, qdot.shape)
                self._inj.log.record(w.index, t)
        if q is reading.q and qdot is reading.qdot:
            return reading
        return JointReading(q, qdot, reading.stamp_s)

    def _stream(self, camera: int) -> _FrameStream:
        stream = self._streams.get(camera)
        if stream is None:
            windows = [w for w in self._frame_windows if w.spec.camera in (None, camera)]
            rngs = {w.index: self._rngs[w.index] if camera == 0 else self._inj.rng(w, camera) for w in windows}
            stream = self._streams[camera] = _FrameStream(windows, rngs, self._inj)
        return stream

    def read_depth(self) -> DepthFrame | None:
        """The backend's latest frame (of the first camera) with the active frame faults applied."""
        return self._stream(0).apply(self._io.read_depth())

    def read_depth_frames(self) -> tuple[DepthFrame | None, ...]:
        """Every camera's latest frame with the frame faults of that camera applied."""
        return tuple(self._stream(c).apply(raw) for c, raw in enumerate(self._io.read_depth_frames()))

    def send_velocity(self, qdot: np.ndarray) -> None:
        """Forwarded."""
        self._io.send_velocity(qdot)

    def wait(self) -> None:
        """Forwarded."""
        self._io.wait()

    def stop(self) -> None:
        """Forwarded."""
        self._io.stop()

    def close(self) -> None:
        """Forwarded."""
        self._io.close()


class _FrameStream:
    """The frame faults of one camera's stream: history (delays), frozen frames, altered copies."""

    def __init__(
        self, windows: list[FaultWindow], rngs: dict[int, np.random.Generator], injector: FaultInjector
    ) -> None:
        self._windows = windows
        self._rngs = rngs
        self._inj = injector
        delays = [w.spec.delay_s for w in windows if w.kind == "depth_delay"]
        self._history: deque[DepthFrame] = deque()
        self._history_s = (max(delays) + 0.2) if delays else 0.0
        self._frozen: dict[int, DepthFrame | None] = {}
        self._last_raw: DepthFrame | None = None
        self._altered: dict[tuple[int, int], DepthFrame] = {}

    def apply(self, raw: DepthFrame | None) -> DepthFrame | None:
        """The frame the controller receives instead of ``raw`` (the backend's latest)."""
        if raw is not None and raw is not self._last_raw:
            self._last_raw = raw
            if self._history_s > 0.0:
                self._history.append(raw)
                while len(self._history) > 2 and raw.stamp_s - self._history[0].stamp_s > self._history_s:
                    self._history.popleft()
        t = self._inj.now()
        frame = raw
        for w in self._windows:
            if not w.active(t):
                if w.kind == "depth_frozen" and t < w.start_s:
                    self._frozen[w.index] = raw  # the frame the camera will be stuck on
                continue
            frame = self._apply(w, frame, t)
        if frame is not raw:
            for w in self._windows:
                if w.active(t):
                    self._inj.log.record(w.index, t)
        return frame

    def _apply(self, w: FaultWindow, frame: DepthFrame | None, t: float) -> DepthFrame | None:
        if w.kind == "depth_frozen":
            return self._frozen.get(w.index, frame)
        if w.kind == "depth_delay":
            due = t - w.spec.delay_s
            older = [f for f in self._history if f.stamp_s <= due + 1e-9]
            if older:
                return older[-1]
            return self._history[0] if self._history else None
        if frame is None:
            return None
        key = (w.index, id(frame))
        cached = self._altered.get(key)
        if cached is not None:
            return cached
        depth = np.array(frame.depth_m, dtype=np.float32, copy=True)
        value = np.nan if w.kind == "depth_nan" else 0.0
        if w.spec.fraction >= 1.0:
            depth[...] = value
        else:
            depth[self._rngs[w.index].random(depth.shape) < w.spec.fraction] = value
        out = DepthFrame(depth, frame.stamp_s, frame.camera)
        self._altered = {key: out}  # one frame per fault is enough: frames do not come back
        return out


class FaultyObstacleSource:
    """Geometric-mode obstacle source with the depth-stream faults emulated (module docstring).

    Args:
        source: The real source (``GeometricObstacleSource``).
        injector: The run's injector.
    """

    def __init__(self, source: ObstacleSource, injector: FaultInjector) -> None:
        self._source = source
        self._inj = injector
        self._windows = injector.of_kind(*FRAME_KINDS)
        delays = [w.spec.delay_s for w in injector.of_kind("depth_delay")]
        self._history_s = (max(delays) + 0.2) if delays else 0.0
        self._history: deque[tuple[float, DistanceResultLike]] = deque()
        self._frozen: dict[int, DistanceResultLike] = {}

    def update(self, t: float, kin: Kinematics) -> DistanceResultLike:
        """The source's update at ``t`` [s], altered by the active faults."""
        result = self._source.update(t, kin)
        if self._history_s > 0.0:
            self._history.append((t, result))
            while len(self._history) > 2 and t - self._history[0][0] > self._history_s:
                self._history.popleft()
        out = result
        for w in self._windows:
            if not w.active(t):
                if w.kind == "depth_frozen" and t < w.start_s:
                    self._frozen[w.index] = result
                continue
            out = self._apply(w, out, t)
            self._inj.log.record(w.index, t)
        return out

    def _apply(self, w: FaultWindow, result: DistanceResultLike, t: float) -> DistanceResultLike:
        if w.kind == "depth_frozen":
            return self._frozen.get(w.index, result)
        if w.kind == "depth_delay":
            due = t - w.spec.delay_s
            older = [r for (ts, r) in self._history if ts <= due + 1e-9]
            return older[-1] if older else self._history[0][1]
        valid = max(0.0, float(getattr(result, "valid_fraction", 1.0)) * (1.0 - w.spec.fraction))
        stamp = float(getattr(result, "stamp_s", t))
        if valid < self._inj.blind_fraction:
            blind = {name: ObstacleReading.nothing() for name in result.readings}
            return cast(DistanceResultLike, DistanceResult(blind, valid, True, stamp))
        kept = cast(dict[str, ObstacleReading], dict(result.readings))
        return cast(DistanceResultLike, DistanceResult(kept, valid, False, stamp))


class FaultySolver:
    """An :class:`~tpik.step_result.IkSolver` that fails or overruns on the configured steps.

    Args:
        solver: The real solver (its ``name`` is kept).
        injector: The run's injector (loop clock, windows, log).
    """

    def __init__(self, solver: IkSolver, injector: FaultInjector) -> None:
        self._solver = solver
        self._inj = injector
        self.name = solver.name
        self._windows = injector.of_kind(*SOLVER_KINDS)
        self._counts = dict.fromkeys((w.index for w in self._windows), 0)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._solver, name)

    def solve(self, hierarchy: Hierarchy, kin: Kinematics, dt: float) -> StepResult:
        """The real solve, unless a fault hits this step."""
        t = self._inj.now()
        hit: FaultWindow | None = None
        for w in self._windows:
            if w.active(t):
                k = self._counts[w.index]
                self._counts[w.index] = k + 1
                if hit is None and k % w.spec.every_n == 0:
                    hit = w
        if hit is None:
            return self._solver.solve(hierarchy, kin, dt)
        self._inj.log.record(hit.index, t)
        if hit.kind == "solver_fail":
            return failed(kin.nq, f"injected solver failure (fault {hit.index})", injected=True)
        start = time.perf_counter()
        result = self._solver.solve(hierarchy, kin, dt)
        if hit.spec.sleep:
            time.sleep(hit.spec.delay_s)
        took = time.perf_counter() - start + (0.0 if hit.spec.sleep else hit.spec.delay_s)
        deadline = hit.spec.deadline_s if hit.spec.deadline_s is not None else self._inj.control_period_s
        if took <= deadline or not math.isfinite(took):
            return result
        # The message names the configured numbers only: events stay reproducible run to run.
        message = f"solver timeout: solve + {1e3 * hit.spec.delay_s:.1f} ms > deadline {1e3 * deadline:.1f} ms"
        return failed(kin.nq, message, injected=True, took_s=took, deadline_miss=True)

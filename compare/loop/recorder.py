"""The per-step table of the closed loop: preallocated arrays, a DataFrame at the end.

Columns (documented in :mod:`compare.analysis.metrics`): ``t``, EE position and target
(``ee_*``, ``target_*``, ``ee_error_m``), ``solve_time_us``, per set task ``sigma:<task>`` and
``active:<task>``, per obstacle task ``truth:<task>``, per control point ``dist_meas:<cp>``,
``dist_true:<cp>``, ``occluded:<cp>`` and ``camera:<cp>`` (with prediction also ``dist_pred:<cp>``
and ``closing_pred:<cp>``), ``waypoint``, ``status``, ``reason``, ``fallback``, ``blind``,
``deadline_miss``, and ``q_j`` / ``qdot_j`` per joint (the sent command).

The loop writes row ``i`` in parts, each a method, into arrays of all steps; the sensing
readings, which change only at a sensing update, are kept once per update and indexed per
step. The table is formed once, at the end (:meth:`StepRecorder.frame`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Protocol, runtime_checkable

import numpy as np
import pandas as pd

from robots import Kinematics
from tpik.tasks import ObstacleDistanceTask, SetTask

_MOTION = ("t", "ee_x", "ee_y", "ee_z", "target_x", "target_y", "target_z", "ee_error_m")

Sensed = tuple[tuple[float, ...], tuple[tuple[bool, str], ...], tuple[tuple[float, float], ...]]
"""The sensing gate's readings of a step: measured distance, (occluded, camera), (predicted distance,
closing speed), each per control point (:class:`~compare.loop.sensing_gate.SensingGate`)."""


@runtime_checkable
class RecordedTruth(Protocol):
    """A ground truth (``truth(kin)``) that also keeps a run's steps and computes them at its end.

    :class:`compare.sensing.ground_truth.GroundTruth`: the same numbers as a call per step.
    """

    def __call__(self, kin: Kinematics) -> Mapping[str, float]:
        """The true distance per control point [m] now."""
        ...

    def start(self, n_steps: int) -> None:
        """Room for a run of ``n_steps`` steps."""
        ...

    def record(self, i: int, kin: Kinematics) -> None:
        """Keep step ``i`` (the control points of ``kin``, the obstacles now)."""
        ...

    def recorded(self, n: int) -> Mapping[str, np.ndarray]:
        """The true distance [m] of steps ``0 .. n-1`` per frame, each (n,)."""
        ...


class StepRecorder:
    """Preallocated per-step columns of one run.

    Args:
        n_steps: Number of rows to allocate.
        nq: Number of joints.
        set_tasks: The hierarchy's set-based tasks (σ and activity recorded).
        obstacle_tasks: Its obstacle tasks (true distance of their frame recorded).
        control_points: The control points (measured and true distances recorded).
        predicted: Record the predicted distance and closing speed of each control point.
    """

    def __init__(
        self,
        n_steps: int,
        nq: int,
        set_tasks: Sequence[SetTask],
        obstacle_tasks: Sequence[ObstacleDistanceTask],
        control_points: Sequence[str],
        predicted: bool = False,
    ) -> None:
        self.n = 0
        self.nq = nq
        self._set_names = tuple(t.name for t in set_tasks)
        self._set_index = {name: k for k, name in enumerate(self._set_names)}
        self._obstacles = tuple((t.name, t.frame) for t in obstacle_tasks)
        self._cps = tuple(control_points)
        self._predicted = predicted
        self._motion = np.full((n_steps, len(_MOTION)), np.nan)
        self._solve_us = np.full(n_steps, np.nan)
        self.q = np.full((n_steps, nq), np.nan)
        self.qdot = np.full((n_steps, nq), np.nan)
        self._sigma = np.full((n_steps, len(self._set_names)), np.nan)
        self._active = np.zeros((n_steps, len(self._set_names)), dtype=bool)
        self._truth = np.full((n_steps, len(self._obstacles)), np.nan)
        self._true = np.full((n_steps, len(self._cps)), np.nan)
        # The gate's readings, once per change, and which of them each step had (-1: none recorded).
        self._sensed: list[Sensed] = []
        self._last_sensed: Sensed | None = None
        self._sensed_at = np.full(n_steps, -1, dtype=np.int64)
        self._waypoint = np.zeros(n_steps, dtype=np.int32)
        self._status = np.empty(n_steps, dtype=object)
        self._reason = np.full(n_steps, "", dtype=object)
        self._fallback = np.zeros(n_steps, dtype=bool)
        self._blind = np.zeros(n_steps, dtype=bool)
        self._missed = np.zeros(n_steps, dtype=bool)

    def motion(
        self, i: int, t: float, ee: Sequence[float], target: Sequence[float], q: np.ndarray, command: np.ndarray
    ) -> None:
        """Row ``i``: time [s], EE position and target [m] (lists) and their distance, joints and command."""
        self._motion[i] = (t, *ee, *target, math.dist(target, ee))
        self.q[i] = q
        self.qdot[i] = command

    def outcome(
        self,
        i: int,
        solve_us: float,
        deadline_miss: bool,
        waypoint: int,
        fallback: str | None,
        blind: bool,
        stopped_why: str | None,
        status: str,
    ) -> None:
        """Row ``i``: solve time [µs], deadline miss, waypoint, fallback, blind, the reason of a stop, status.

        Args:
            i: Row.
            solve_us: Solve time [µs].
            deadline_miss: The solve missed its deadline.
            waypoint: Index of the current waypoint.
            fallback: Why the fallback was sent, or None.
            blind: Sensing is blind or stale.
            stopped_why: Why sensing stopped the robot (blind or stale), or None.
            status: ``ok`` / ``degraded`` / ``failed``; the row is complete.
        """
        self._solve_us[i] = solve_us
        self._missed[i] = deadline_miss
        self._waypoint[i] = waypoint
        self._blind[i] = blind
        if fallback is not None or stopped_why is not None:
            self._fallback[i] = fallback is not None
            parts = [f"sensing: {stopped_why}"] if stopped_why is not None else []
            self._reason[i] = "; ".join(parts + ([f"fallback: {fallback}"] if fallback is not None else []))
        self._status[i] = status
        self.n = i + 1

    def set_tasks(self, i: int, sigmas: Sequence[float], active: Sequence[str]) -> None:
        """Row ``i``: σ of every set task (in the hierarchy's order) and whether it is in the active set."""
        self._sigma[i] = sigmas
        row = self._active[i]
        for name in active:
            k = self._set_index.get(name)
            if k is not None:
                row[k] = True

    def distances(self, i: int, sensed: Sensed, true_d: Mapping[str, float] | None) -> None:
        """Row ``i``: the gate's readings and the true distances [m] (inf for a frame the truth lacks).

        The readings are kept by reference, once per change (the gate replaces them, never changes
        them). ``true_d`` None: the true distances come with :meth:`true_distances`, at the end.
        """
        last = self._last_sensed
        if last is None or sensed[0] is not last[0] or sensed[1] is not last[1] or sensed[2] is not last[2]:
            self._sensed.append(sensed)
            self._last_sensed = sensed
        self._sensed_at[i] = len(self._sensed) - 1
        if true_d:
            self._true[i] = [true_d.get(cp, math.inf) for cp in self._cps]
            self._truth[i] = [true_d.get(frame, math.inf) for _, frame in self._obstacles]
        elif true_d is not None:
            self._true[i] = math.inf
            self._truth[i] = math.inf

    def true_distances(self, per_frame: Mapping[str, np.ndarray]) -> None:
        """The true distance [m] of every row recorded so far, per frame (inf for a frame not given)."""
        n = self.n
        recorded = self._sensed_at[:n] >= 0
        missing = np.where(recorded, math.inf, np.nan)
        for k, cp in enumerate(self._cps):
            self._true[:n, k] = np.where(recorded, per_frame[cp][:n], np.nan) if cp in per_frame else missing
        for k, (_, frame) in enumerate(self._obstacles):
            self._truth[:n, k] = np.where(recorded, per_frame[frame][:n], np.nan) if frame in per_frame else missing

    def frame(self) -> pd.DataFrame:
        """The rows recorded so far as a DataFrame."""
        n = self.n
        cols: dict[str, np.ndarray] = {name: self._motion[:n, k] for k, name in enumerate(_MOTION)}
        cols["solve_time_us"] = self._solve_us[:n]
        for k, name in enumerate(self._set_names):
            cols[f"sigma:{name}"] = self._sigma[:n, k]
            cols[f"active:{name}"] = self._active[:n, k]
        for k, (name, _) in enumerate(self._obstacles):
            cols[f"truth:{name}"] = self._truth[:n, k]
        cols.update(self._sensing_columns())
        cols["waypoint"] = self._waypoint[:n]
        cols["status"] = self._status[:n]
        cols["reason"] = self._reason[:n]
        cols["fallback"] = self._fallback[:n]
        cols["blind"] = self._blind[:n]
        cols["deadline_miss"] = self._missed[:n]
        for j in range(self.nq):
            cols[f"q_{j + 1}"] = self.q[:n, j]
            cols[f"qdot_{j + 1}"] = self.qdot[:n, j]
        return pd.DataFrame(cols)

    def _sensing_columns(self) -> dict[str, np.ndarray]:
        """Per control point: measured and true distance, occluded, camera (and the prediction) of each row."""
        n, k_cp = self.n, len(self._cps)
        # One row per kept reading, then the row of a step without one (NaN, False, ""): index -1.
        sensed = [*self._sensed, ((math.nan,) * k_cp, ((False, ""),) * k_cp, ((math.nan, math.nan),) * k_cp)]
        measured = np.array([meas for meas, _, _ in sensed], dtype=float).reshape(len(sensed), k_cp)
        occluded = np.array([[occ for occ, _ in source] for _, source, _ in sensed], dtype=bool).reshape(measured.shape)
        camera = np.array([[cam for _, cam in source] for _, source, _ in sensed], dtype=object).reshape(measured.shape)
        predicted = np.array([pred for _, _, pred in sensed], dtype=float).reshape(len(sensed), k_cp, 2)
        at = self._sensed_at[:n]
        cols: dict[str, np.ndarray] = {}
        for c, cp in enumerate(self._cps):
            cols[f"dist_meas:{cp}"] = measured[at, c]
            cols[f"dist_true:{cp}"] = self._true[:n, c]
            cols[f"occluded:{cp}"] = occluded[at, c]
            cols[f"camera:{cp}"] = camera[at, c]
            if self._predicted:
                cols[f"dist_pred:{cp}"] = predicted[at, c, 0]
                cols[f"closing_pred:{cp}"] = predicted[at, c, 1]
        return cols

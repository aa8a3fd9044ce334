"""The per-step table of the closed loop: preallocated columns, a DataFrame at the end.

Columns (documented in :mod:`compare.analysis.metrics`): ``t``, EE position and target
(``ee_*``, ``target_*``, ``ee_error_m``), ``solve_time_us``, ``deadline_miss``, ``waypoint``,
``status``, ``reason``, ``fallback``, ``blind``, per set task ``sigma:<task>`` and
``active:<task>``, per obstacle task ``truth:<task>``, per control point ``dist_meas:<cp>``,
``dist_true:<cp>``, ``occluded:<cp>`` and ``camera:<cp>`` (with prediction also ``dist_pred:<cp>``
and ``closing_pred:<cp>``), and ``q_j`` / ``qdot_j`` per joint
(the sent command). The loop writes row ``i`` in parts, each a method; nothing is allocated per
step beyond the values themselves (recording is a noticeable share of a fast run).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np
import pandas as pd

from robots import Kinematics
from tpik.tasks import ObstacleDistanceTask, SetTask

_FLOATS = ("t", "ee_x", "ee_y", "ee_z", "target_x", "target_y", "target_z", "ee_error_m", "solve_time_us")


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
        cols: dict[str, np.ndarray] = {}
        self.cols = cols
        for name in _FLOATS:
            cols[name] = np.full(n_steps, np.nan)
        self.q = np.full((n_steps, nq), np.nan)
        self.qdot = np.full((n_steps, nq), np.nan)
        for task in set_tasks:
            cols[f"sigma:{task.name}"] = np.full(n_steps, np.nan)
            cols[f"active:{task.name}"] = np.zeros(n_steps, dtype=bool)
        for task in obstacle_tasks:
            cols[f"truth:{task.name}"] = np.full(n_steps, np.nan)
        for cp in control_points:
            cols[f"dist_meas:{cp}"] = np.full(n_steps, np.nan)
            cols[f"dist_true:{cp}"] = np.full(n_steps, np.nan)
            cols[f"occluded:{cp}"] = np.zeros(n_steps, dtype=bool)
            cols[f"camera:{cp}"] = np.full(n_steps, "", dtype=object)
            if predicted:
                cols[f"dist_pred:{cp}"] = np.full(n_steps, np.nan)
                cols[f"closing_pred:{cp}"] = np.full(n_steps, np.nan)
        cols["waypoint"] = np.zeros(n_steps, dtype=np.int32)
        cols["status"] = np.empty(n_steps, dtype=object)
        cols["reason"] = np.full(n_steps, "", dtype=object)
        for name in ("fallback", "blind", "deadline_miss"):
            cols[name] = np.zeros(n_steps, dtype=bool)
        # Column arrays and σ functions looked up once. σ alone (SetTask.compute_value): the
        # solver already formed the Jacobians it needed.
        self._sigma = [(cols[f"sigma:{t.name}"], cols[f"active:{t.name}"], t.name, t.compute_value) for t in set_tasks]
        self._dist = [(cols[f"dist_meas:{cp}"], cols[f"dist_true:{cp}"], cp) for cp in control_points]
        self._source = [(cols[f"occluded:{cp}"], cols[f"camera:{cp}"], cp) for cp in control_points]
        self._truth = [(cols[f"truth:{t.name}"], t.frame) for t in obstacle_tasks]
        self._predicted = (
            [(cols[f"dist_pred:{cp}"], cols[f"closing_pred:{cp}"], cp) for cp in control_points] if predicted else []
        )
        self._ee = (cols["ee_x"], cols["ee_y"], cols["ee_z"])
        self._target = (cols["target_x"], cols["target_y"], cols["target_z"])
        self.sigmas = [math.nan] * len(self._sigma)
        """σ of every set task at the last recorded step (in the hierarchy's order)."""

    def motion(self, i: int, t: float, ee: np.ndarray, target: np.ndarray, q: np.ndarray, command: np.ndarray) -> None:
        """Row ``i``: time [s], EE position and target [m] and their distance, joints and command."""
        cols = self.cols
        cols["t"][i] = t
        c_x, c_y, c_z = self._ee
        c_x[i], c_y[i], c_z[i] = ee
        c_x, c_y, c_z = self._target
        c_x[i], c_y[i], c_z[i] = target
        cols["ee_error_m"][i] = math.dist(target, ee)
        self.q[i] = q
        self.qdot[i] = command

    def flags(
        self,
        i: int,
        solve_us: float,
        deadline_miss: bool,
        waypoint: int,
        fallback: str | None,
        blind: bool,
        stopped_why: str | None,
    ) -> None:
        """Row ``i``: solve time [µs], deadline miss, waypoint, fallback, blind and the reason of a stop.

        Args:
            i: Row.
            solve_us: Solve time [µs].
            deadline_miss: The solve missed its deadline.
            waypoint: Index of the current waypoint.
            fallback: Why the fallback was sent, or None.
            blind: Sensing is blind or stale.
            stopped_why: Why sensing stopped the robot (blind or stale), or None.
        """
        cols = self.cols
        cols["solve_time_us"][i] = solve_us
        cols["deadline_miss"][i] = deadline_miss
        cols["waypoint"][i] = waypoint
        cols["fallback"][i] = fallback is not None
        cols["blind"][i] = blind
        if fallback is not None or stopped_why is not None:
            parts = [f"sensing: {stopped_why}"] if stopped_why is not None else []
            cols["reason"][i] = "; ".join(parts + ([f"fallback: {fallback}"] if fallback is not None else []))

    def set_tasks(self, i: int, kin: Kinematics, active: Sequence[str]) -> list[float]:
        """Row ``i``: σ and activity of every set task at ``kin``; returns the σ (:attr:`sigmas`)."""
        active_names = set(active)
        sigmas = self.sigmas
        for k, (c_sigma, c_active, name, value) in enumerate(self._sigma):
            sigmas[k] = c_sigma[i] = value(kin)
            c_active[i] = name in active_names
        return sigmas

    def distances(
        self,
        i: int,
        measured: Mapping[str, float],
        source: Mapping[str, tuple[bool, str]],
        true_d: Mapping[str, float],
    ) -> None:
        """Row ``i``: measured and true distance per control point [m], the reading's kind and camera."""
        for c_meas, c_true, cp in self._dist:
            c_meas[i] = measured[cp]
            c_true[i] = true_d.get(cp, math.inf)
        for c_occ, c_cam, cp in self._source:
            c_occ[i], c_cam[i] = source[cp]
        for c_truth, frame in self._truth:
            c_truth[i] = true_d.get(frame, math.inf)

    def predictions(self, i: int, predicted: Mapping[str, tuple[float, float]]) -> None:
        """Row ``i``: predicted distance [m] and closing speed [m/s] per control point."""
        for c_dist, c_closing, cp in self._predicted:
            c_dist[i], c_closing[i] = predicted[cp]

    def status(self, i: int, status: str) -> None:
        """Row ``i``'s status (``ok`` / ``degraded`` / ``failed``); the row is complete."""
        self.cols["status"][i] = status
        self.n = i + 1

    def frame(self) -> pd.DataFrame:
        """The rows recorded so far as a DataFrame."""
        cols = {k: v[: self.n] for k, v in self.cols.items()}
        for j in range(self.nq):
            cols[f"q_{j + 1}"] = self.q[: self.n, j]
            cols[f"qdot_{j + 1}"] = self.qdot[: self.n, j]
        return pd.DataFrame(cols)

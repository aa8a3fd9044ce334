r"""Speed-and-separation margin of ISO/TS 15066:2016, clause 5.5.4, per step and control point.

ISO/TS 15066:2016 clause 5.5.4 (speed and separation monitoring), formula (1), gives the
protective separation distance at the current time :math:`t_0`:

.. math::
    S_p(t_0) = S_h + S_r + S_s + C + Z_d + Z_r

* :math:`S_h` — the operator's motion during the robot's reaction and stopping time. With the
  operator's directed speed :math:`v_h` toward the robot taken constant over that time (the
  clause's own simplification), :math:`S_h = v_h\,(T_r + T_s)`;
* :math:`S_r = v_r\,T_r` — the robot's motion during its reaction time, :math:`v_r` its directed
  speed toward the operator;
* :math:`S_s` — the robot's stopping distance; here :math:`v_r T_s / 2` (constant deceleration
  over :math:`T_s`) unless ``[iso15066] stopping_distance_m`` is given;
* :math:`C` — intrusion distance (reach past the detection zone), :math:`Z_d` — position
  uncertainty of the operator (sensing), :math:`Z_r` — position uncertainty of the robot.

The *margin* of a control point is the separation the controller measured minus :math:`S_p`:

.. math:: m = \|O - P\| - S_p

with :math:`O` the closest obstacle point of the latest usable sensing update (held between
updates, exactly as the obstacle task uses it) and :math:`P` the control point at the step.
:math:`m < 0`: the robot could not stop before contact if the person kept coming at :math:`v_h`.

Speeds:

* :math:`v_h` is **estimated from the sensing**, not taken from the simulator: between two
  consecutive usable updates :math:`k-1, k` of a control point,
  :math:`\hat v = \max\!\big(0,\ (O_k - O_{k-1}) \cdot u_k / (t_k - t_{k-1})\big)` with
  :math:`u_k = (P_k - O_k)/\|P_k - O_k\|` (motion of the measured closest point toward the
  control point), clipped to ``human_speed_max_mps`` (a jump of the closest point from one body
  part to another is not a speed) and filtered with a first-order low-pass of time constant
  ``human_speed_filter_s``: :math:`v_h \leftarrow v_h + \alpha(\hat v - v_h)`,
  :math:`\alpha = \Delta t / (\tau + \Delta t)`. The estimate of a control point restarts from 0
  when its obstacle leaves the range ρ. ``human_speed = "constant"`` uses ``human_speed_mps``
  (ISO 13855's 1.6 m/s) instead;
* :math:`v_r = \max(0, \dot P \cdot (O - P)/\|O - P\|)`, :math:`\dot P` from the measured joint
  positions of consecutive steps (backward difference).

Steps where a control point has no obstacle in range have no margin (NaN: nothing within ρ).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numba
import numpy as np
import pandas as pd

from compare.config import Iso15066Config
from compare.loop.closed_loop import DistanceResultLike, ObstacleSource, sensing_problem
from compare.loop.numpy_dot import NUMPY_DOT_FUSED, dot3
from robots import Kinematics, Robot


@dataclass(frozen=True)
class IsoParameters:
    """The constants of :func:`protective_separation_distance` (``[iso15066]``).

    Attributes:
        reaction_time_s: T_r [s].
        stopping_time_s: T_s [s].
        stopping_distance_m: S_s [m]; None = :math:`v_r T_s / 2`.
        intrusion_distance_m: C [m].
        sensor_uncertainty_m: Z_d [m].
        robot_uncertainty_m: Z_r [m].
    """

    reaction_time_s: float = 0.1
    stopping_time_s: float = 0.2
    stopping_distance_m: float | None = None
    intrusion_distance_m: float = 0.0
    sensor_uncertainty_m: float = 0.02
    robot_uncertainty_m: float = 0.01

    @classmethod
    def from_config(cls, cfg: Iso15066Config) -> IsoParameters:
        """From the ``[iso15066]`` section."""
        return cls(
            cfg.reaction_time_s,
            cfg.stopping_time_s,
            cfg.stopping_distance_m,
            cfg.intrusion_distance_m,
            cfg.sensor_uncertainty_m,
            cfg.robot_uncertainty_m,
        )


def separation_terms(v_h: np.ndarray | float, v_r: np.ndarray | float, params: IsoParameters) -> dict[str, np.ndarray]:
    r"""The terms of ISO/TS 15066 clause 5.5.4 formula (1) [m], element-wise.

    .. math::
        S_h = v_h (T_r + T_s),\quad S_r = v_r T_r,\quad S_s = v_r T_s / 2 \text{ (or configured)},
        \quad S_p = S_h + S_r + S_s + C + Z_d + Z_r

    Args:
        v_h: Operator's directed speed toward the robot [m/s] (≥ 0).
        v_r: Robot's directed speed toward the operator [m/s] (≥ 0).
        params: Times, stopping distance and uncertainty terms.

    Returns:
        ``{"S_h", "S_r", "S_s", "C", "Z_d", "Z_r", "S_p"}`` as arrays of the broadcast shape.
    """
    vh = np.asarray(v_h, dtype=float)
    vr = np.asarray(v_r, dtype=float)
    shape = np.broadcast(vh, vr).shape
    s_h = vh * (params.reaction_time_s + params.stopping_time_s)
    s_r = vr * params.reaction_time_s
    if params.stopping_distance_m is None:
        s_s = vr * params.stopping_time_s / 2.0
    else:
        s_s = np.full(shape, params.stopping_distance_m)
    const = {
        "C": np.full(shape, params.intrusion_distance_m),
        "Z_d": np.full(shape, params.sensor_uncertainty_m),
        "Z_r": np.full(shape, params.robot_uncertainty_m),
    }
    s_p = s_h + s_r + s_s + const["C"] + const["Z_d"] + const["Z_r"]
    return {
        "S_h": np.broadcast_to(s_h, shape),
        "S_r": np.broadcast_to(s_r, shape),
        "S_s": np.broadcast_to(s_s, shape),
        **const,
        "S_p": np.broadcast_to(s_p, shape),
    }


def protective_separation_distance(
    v_h: np.ndarray | float, v_r: np.ndarray | float, params: IsoParameters
) -> np.ndarray | float:
    r"""ISO/TS 15066:2016 clause 5.5.4, formula (1), constant speeds over :math:`T_r + T_s` [m].

    .. math:: S_p = v_h (T_r + T_s) + v_r T_r + S_s + C + Z_d + Z_r

    Args:
        v_h: Operator's directed speed toward the robot [m/s].
        v_r: Robot's directed speed toward the operator [m/s].
        params: The constants.

    Returns:
        S_p [m] (a float for scalar inputs).
    """
    s_p = separation_terms(v_h, v_r, params)["S_p"]
    return float(s_p) if s_p.ndim == 0 else np.array(s_p)


def separation_margin(
    distance_m: np.ndarray | float, v_h: np.ndarray | float, v_r: np.ndarray | float, params: IsoParameters
) -> np.ndarray | float:
    r"""Measured separation minus the protective separation distance [m]: :math:`d - S_p`."""
    m = np.asarray(distance_m, dtype=float) - separation_terms(v_h, v_r, params)["S_p"]
    return float(m) if m.ndim == 0 else np.array(m)


@dataclass
class _Update:
    t: float
    usable: bool
    points: np.ndarray  # closest obstacle point O per control point [m], (F, 3); NaN rows where none in range
    control_points: np.ndarray  # P of each frame at the update [m], (F, 3)


@numba.njit(cache=True, nogil=True)
def _filtered_speeds(
    t: np.ndarray,
    points: np.ndarray,
    control_points: np.ndarray,
    constant: bool,
    speed_mps: float,
    max_mps: float,
    filter_s: float,
    fused: bool,
    out: np.ndarray,
) -> None:
    r"""The low-passed speed :math:`v_h` toward each control point at each update into ``out`` (U, F) (module doc).

    ``t`` (U,) [s], ``points`` O (U, F, 3) [m] (a non-finite row: none in range), ``control_points`` P
    (U, F, 3) [m]; ``out`` starts at zero and stays zero at a non-finite row. The dot products are numpy's
    (:func:`~compare.loop.numpy_dot.dot3`, ``fused`` as numpy's), the rest IEEE operations in the
    order of the formula, so the result is the numpy computation's bit for bit.
    """
    for c in range(points.shape[1]):
        est = 0.0
        seen = False
        prev_t = 0.0
        p0 = p1 = p2 = 0.0
        for k in range(points.shape[0]):
            if not np.isfinite(points[k, c, 0]):
                est = 0.0
                seen = False
                continue
            o0, o1, o2 = points[k, c, 0], points[k, c, 1], points[k, c, 2]
            if constant:
                est = speed_mps
            elif seen and t[k] > prev_t:
                gap = t[k] - prev_t
                a0, a1, a2 = control_points[k, c, 0] - o0, control_points[k, c, 1] - o1, control_points[k, c, 2] - o2
                n = np.sqrt(dot3(a0, a1, a2, a0, a1, a2, fused))
                raw = dot3(o0 - p0, o1 - p1, o2 - p2, a0, a1, a2, fused) / (n * gap) if n > 1e-9 else 0.0
                if 0.0 > raw:  # max(raw, 0), then min(·, max_mps): Python's order of comparison
                    raw = 0.0
                if max_mps < raw:
                    raw = max_mps
                alpha = gap / (filter_s + gap)
                est += alpha * (raw - est)
            prev_t = t[k]
            p0, p1, p2 = o0, o1, o2
            seen = True
            out[k, c] = est


@dataclass
class SeparationMonitor:
    """An :class:`~compare.loop.closed_loop.ObstacleSource` wrapper that records what the controller senses.

    Sits between the (possibly faulty) source and the loop; every update is passed through
    unchanged and logged with the control point positions, and :meth:`margins` turns the log and
    the per-step table into the per-step margins.

    Args:
        source: The obstacle source the loop would use.
        stale_after_s: The loop's stale-frame age [s] (``stale_frame_periods`` × period), so the
            monitor trusts exactly the updates the loop trusts.
        frames: Control point frames (``compare.loop.closed_loop.control_points``).
    """

    source: ObstacleSource
    stale_after_s: float | None = None
    frames: tuple[str, ...] = ()
    updates: list[_Update] = field(default_factory=list)

    def update(self, t: float, kin: Kinematics) -> DistanceResultLike:
        """Forward to the source and record the update."""
        result = self.source.update(t, kin)
        usable = sensing_problem(result, t, self.stale_after_s) is None
        points = np.full((len(self.frames), 3), np.nan)
        if usable:  # a usable update's points in range are finite (sensing_problem)
            for c, cp in enumerate(self.frames):
                r = result.readings.get(cp)
                if r is not None and r.in_range and r.closest_point is not None:
                    points[c] = r.closest_point
        positions = np.empty((len(self.frames), 3))
        kin.frame_positions(self.frames, positions)
        self.updates.append(_Update(t, usable, points, positions))
        return result

    def human_speeds(self, cfg: Iso15066Config) -> tuple[np.ndarray, dict[str, np.ndarray], dict[str, np.ndarray]]:
        """Per usable update: times, v_h estimate and closest point per control point.

        Returns:
            ``(t (U,), {cp: v_h (U,)}, {cp: O (U, 3), NaN rows when nothing in range})``.
        """
        ups = [u for u in self.updates if u.usable]
        t = np.array([u.t for u in ups], dtype=float)
        shape = (len(ups), len(self.frames))
        points = np.array([u.points for u in ups], dtype=float).reshape(*shape, 3)
        positions = np.array([u.control_points for u in ups], dtype=float).reshape(*shape, 3)
        v = np.zeros(shape)
        constant = cfg.human_speed == "constant"
        fused = NUMPY_DOT_FUSED is not False  # numpy's order here; fused where numpy's is neither
        _filtered_speeds(
            t,
            points,
            positions,
            constant,
            float(cfg.human_speed_mps),
            float(cfg.human_speed_max_mps),
            float(cfg.human_speed_filter_s),
            fused,
            v,
        )
        v_h = {cp: v[:, c].copy() for c, cp in enumerate(self.frames)}
        pts = {cp: points[:, c].copy() for c, cp in enumerate(self.frames)}
        return t, v_h, pts

    def margins(
        self, steps: pd.DataFrame, robot: Robot, cfg: Iso15066Config, known: np.ndarray | None = None
    ) -> pd.DataFrame:
        """Per-step ISO columns for every control point ``cp``.

        ``iso_margin_m:cp`` (d − S_p [m], NaN without obstacle in range), ``iso_sp_m:cp`` (S_p),
        ``iso_vh_mps:cp`` (estimated v_h), ``iso_vr_mps:cp`` (v_r toward the person).

        Args:
            steps: The loop's per-step table (``t``, ``q_1..q_n``).
            robot: The arm model (forward kinematics of the recorded joint positions).
            cfg: ``[iso15066]``.
            known: The control points of every step as the loop recorded them [m], (n, F, 3) in
                :attr:`frames` order, NaN rows where not recorded (those are computed from ``q``).

        Raises:
            ValueError: ``known`` is not of shape (n, F, 3).
        """
        n = len(steps)
        out = {
            f"iso_{k}:{cp}": np.full(n, np.nan) for k in ("margin_m", "sp_m", "vh_mps", "vr_mps") for cp in self.frames
        }
        if n == 0:
            return pd.DataFrame(out, index=steps.index)
        t_u, v_h, pts = self.human_speeds(cfg)
        t = steps["t"].to_numpy(dtype=float)
        k_u = np.searchsorted(t_u, t + 1e-9) - 1  # latest usable update at or before each step
        have = np.zeros(n, dtype=bool)
        for cp in self.frames:
            ok = k_u >= 0
            ok[ok] = np.isfinite(pts[cp][k_u[ok], 0])
            have |= ok
        if not np.any(have):
            return pd.DataFrame(out, index=steps.index)
        qcols = [f"q_{j}" for j in range(1, robot.nq + 1)]
        q = steps[qcols].to_numpy(dtype=float)
        need = have | np.roll(have, -1)  # P of the step before each monitored step, for Ṗ
        shape = (n, len(self.frames), 3)
        points = np.full(shape, np.nan)
        if known is not None:  # the same q's kinematics, computed by the loop
            if known.shape != shape:
                raise ValueError(f"known control points must have shape {shape}, got {known.shape}")
            points[need] = known[need]
        for i in np.flatnonzero(need & np.isnan(points[:, 0, 0])):
            if np.all(np.isfinite(q[i])):
                robot.kinematics(q[i]).frame_positions(self.frames, points[i])
        positions = {cp: np.ascontiguousarray(points[:, k]) for k, cp in enumerate(self.frames)}
        params = IsoParameters.from_config(cfg)
        dt = np.diff(t, prepend=np.nan)
        for cp in self.frames:
            idx = np.flatnonzero(k_u >= 0)
            o = np.full((n, 3), np.nan)
            o[idx] = pts[cp][k_u[idx]]
            vh = np.full(n, np.nan)
            vh[idx] = v_h[cp][k_u[idx]]
            p = positions[cp]
            diff = o - p
            dist = np.linalg.norm(diff, axis=1)
            with np.errstate(invalid="ignore", divide="ignore"):
                p_dot = np.vstack([np.zeros((1, 3)), np.diff(p, axis=0)]) / dt[:, None]
                toward = np.einsum("ij,ij->i", p_dot, diff) / dist
            v_r = np.where(np.isfinite(toward), np.maximum(toward, 0.0), 0.0)
            valid = np.isfinite(dist) & np.isfinite(vh)
            s_p = np.where(valid, separation_terms(np.nan_to_num(vh), v_r, params)["S_p"], np.nan)
            out[f"iso_margin_m:{cp}"] = np.where(valid, dist - s_p, np.nan)
            out[f"iso_sp_m:{cp}"] = s_p
            out[f"iso_vh_mps:{cp}"] = np.where(valid, vh, np.nan)
            out[f"iso_vr_mps:{cp}"] = np.where(valid, v_r, np.nan)
        return pd.DataFrame(out, index=steps.index)


def summarize(steps: pd.DataFrame, dt: float, cfg: Iso15066Config, control_points: Sequence[str]) -> dict[str, Any]:
    """The ``iso15066`` entry of a method in ``summary.json`` from the ``iso_*`` columns.

    Returns:
        ``{"min_margin_m", "time_below_zero_s", "monitored_time_s", "human_speed_max_mps",
        "robot_speed_toward_person_max_mps", "per_control_point": {cp: {"min_margin_m",
        "time_below_zero_s"}}, "parameters": {...}}``; margins ``None`` when the person was never
        within range.
    """
    per_cp: dict[str, dict[str, Any]] = {}
    n = len(steps)
    below_any = np.zeros(n, dtype=bool)
    monitored = np.zeros(n, dtype=bool)
    mins: list[float] = []
    vh_max: list[float] = []
    vr_max: list[float] = []
    for cp in control_points:
        col = f"iso_margin_m:{cp}"
        m = steps[col].to_numpy(dtype=float) if col in steps.columns else np.full(n, np.nan)
        finite = np.isfinite(m)
        below = finite & (m < 0.0)
        below_any |= below
        monitored |= finite
        cp_min = float(m[finite].min()) if np.any(finite) else None
        if cp_min is not None:
            mins.append(cp_min)
        per_cp[cp] = {"min_margin_m": cp_min, "time_below_zero_s": float(np.count_nonzero(below) * dt)}
        for key, acc in (("vh_mps", vh_max), ("vr_mps", vr_max)):
            c = f"iso_{key}:{cp}"
            if c in steps.columns:
                v = steps[c].to_numpy(dtype=float)
                if np.any(np.isfinite(v)):
                    acc.append(float(np.nanmax(v)))
    return {
        "min_margin_m": min(mins) if mins else None,
        "time_below_zero_s": float(np.count_nonzero(below_any) * dt),
        "monitored_time_s": float(np.count_nonzero(monitored) * dt),
        "human_speed_max_mps": max(vh_max) if vh_max else None,
        "robot_speed_toward_person_max_mps": max(vr_max) if vr_max else None,
        "per_control_point": per_cp,
        "parameters": parameters_dict(cfg),
    }


def parameters_dict(cfg: Iso15066Config) -> dict[str, Any]:
    """The ISO constants as stored in ``summary.json`` (S_s ``None`` = :math:`v_r T_s / 2`)."""
    return {
        "reaction_time_s": cfg.reaction_time_s,
        "stopping_time_s": cfg.stopping_time_s,
        "stopping_distance_m": cfg.stopping_distance_m,
        "intrusion_distance_m": cfg.intrusion_distance_m,
        "sensor_uncertainty_m": cfg.sensor_uncertainty_m,
        "robot_uncertainty_m": cfg.robot_uncertainty_m,
        "human_speed": cfg.human_speed,
        "human_speed_mps": cfg.human_speed_mps if cfg.human_speed == "constant" else None,
        "human_speed_filter_s": cfg.human_speed_filter_s,
        "human_speed_max_mps": cfg.human_speed_max_mps,
    }


def min_margin_by_point(summary: Mapping[str, Any]) -> dict[str, float | None]:
    """``{cp: min margin}`` of a method's ``iso15066`` entry (empty when absent)."""
    iso = summary.get("iso15066") or {}
    return {cp: v.get("min_margin_m") for cp, v in (iso.get("per_control_point") or {}).items()}


__all__ = [
    "IsoParameters",
    "SeparationMonitor",
    "min_margin_by_point",
    "parameters_dict",
    "protective_separation_distance",
    "separation_margin",
    "separation_terms",
    "summarize",
]

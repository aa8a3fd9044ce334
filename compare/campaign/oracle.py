r"""A clairvoyant reference controller: what the best-informed arm could have done (DESIGN §5, §7).

The person in a simulated scenario follows scripted keyframes and does not react to the arm, so
their whole future motion is known in advance. The oracle uses it: a receding-horizon optimiser
over the arm's joint velocities that maximises the smallest distance between the control points
and the person over the next T seconds, under the same limits every method has to respect. It
has no mission (no waypoints) and only asks how far from the person the arm can stay.

**Formulation.** At time :math:`t` with measured joints :math:`q_0`, the plan is N = ⌈T/h⌉
piecewise-constant joint velocities :math:`u_0..u_{N-1}` (knot h), :math:`q_i = q_0 + h\sum_{j<i}
u_j`. With :math:`m_{i,c}(q_i)` the margin of control point c to its safety threshold at knot i
(:math:`m = d - \sigma_{s}`; d the distance to the person's capsules at time :math:`t + ih`),

.. math::
    \max_{u,\,s,\,s_i,\,w}\ s + \frac{\mu}{N}\sum_i s_i - \frac{\epsilon}{2}\|u\|^2 - \rho w
    \quad\text{s.t.}\quad
    \begin{cases}
      s \le s_i \le \min_c m_{i,c}(q_i),\ \ s_i \le \bar m & \text{(max-min margin, capped at } \bar m)\\
      \sigma_{s,l} - w \le \sigma_k(q_i) \le \sigma_{s,u} + w & \text{(every other set task: joint limits, walls)}\\
      q_{min} \le q_i \le q_{max},\quad |u_i| \le v_{max} & \text{(the robot's hard limits)}
    \end{cases}

solved by sequential QP: each iteration linearises the distances (one row per control point and
person capsule, gradient :math:`n^T J_c` with n the unit vector from the capsule's closest point,
the envelope theorem) and the set tasks around the rollout of the current plan, bounds the change
of every knot velocity by a trust region, and solves the QP with a qpsolvers backend
(``[oracle] solver``, DAQP by default). Of the candidate plans (the previous plan shifted, each
iterate) the one with the best *true* objective (exact distances along its rollout) is kept.
The cap :math:`\bar m` makes holding still optimal when it already keeps every control point
:math:`\bar m` beyond its threshold over the whole horizon: then no QP is solved. The plan is
re-optimised every ``replan_period_s`` and followed in between.

The oracle drives the same plant as the methods (same simulation mode, joint drive, control
period), through :func:`compare.loop.closed_loop.run_loop` without sensing, and its run is scored
by the same metrics (ground-truth distances of the control points): ``held_safety`` is true when
its obstacle group has no violation (margin below −1 mm).

**What it guarantees, and what not.** ``held_safety = true`` is a witness: a joint-velocity
trajectory within the same joint position and velocity limits, joint-limit and wall safety
thresholds, executed on the same plant, kept every control point beyond the safety threshold, so a
method's violation in that run was avoidable (with foreknowledge). ``held_safety = false`` is not a
proof that no trajectory exists: a longer horizon, a global planner or more iterations might find
one (the optimisation is local and non-convex). The oracle ignores the mission and injected faults,
knows the future exactly (no sensing, no latency), and tracks its own commands through the plant's
lag; it has no acceleration limit beyond what the plant imposes, like the methods.
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import qpsolvers

import robots
from compare.analysis.metrics import compute_summary, to_jsonable
from compare.config import Config, OracleConfig
from compare.loop.closed_loop import run_loop
from compare.loop.simulation import build_simulation
from compare.sensing.person import Person
from robots import Kinematics
from tpik.hierarchy import Hierarchy
from tpik.step_result import SolveStatus, StepResult
from tpik.tasks import ObstacleDistanceTask, SetTask

log = logging.getLogger(__name__)

ORACLE_VERSION = 1
"""Bumped whenever the formulation changes: part of the cache key."""

ORACLE_METHOD = "oracle"
"""Name of the oracle in logs and per-step tables (it is not a method of the comparison)."""

_SLACK_WEIGHT = 100.0  # ρ: exact-penalty weight of the set-task slack w (per task unit)
_EFFORT_WEIGHT = 1e-3  # ε on ‖u‖² [1/(rad/s)²]: small next to 1 m of margin
_TINY = 1e-6  # keeps the Hessian of s, s_i positive definite (DAQP, quadprog need it)
_ROW_CUTOFF_M = 0.3  # distance rows kept when the margin is below the cap + this [m]


# ------------------------------------------------------------------------------------ person


@dataclass(frozen=True)
class PersonTrack:
    """The person's capsules sampled on a time grid (computed once, looked up at any time).

    Attributes:
        step_s: Grid step [s].
        a: Capsule segment starts [m]. Shape (T, G, 3).
        b: Capsule segment ends [m] (= ``a`` for spheres). Shape (T, G, 3).
        radius: Capsule radii [m]. Shape (G,).
    """

    step_s: float
    a: np.ndarray
    b: np.ndarray
    radius: np.ndarray

    @classmethod
    def from_person(cls, person: Person, end_s: float, step_s: float) -> PersonTrack:
        """Sample :meth:`Person.capsules_at` every ``step_s`` from 0 to ``end_s`` [s].

        While the person's pose does not change (between keyframes of a hold) the previous
        sample is copied instead of recomputed.
        """
        n = max(2, int(math.ceil(end_s / step_s)) + 2)
        names = sorted(person.capsules_at(0.0))
        a = np.empty((n, len(names), 3))
        b = np.empty((n, len(names), 3))
        radius = np.zeros(len(names))
        previous: tuple[float, ...] | None = None
        for k in range(n):
            pose = person.pose_at(k * step_s)
            signature = (*pose.position, pose.yaw, *pose.hands["r"], *pose.hands["l"])
            if signature == previous:
                a[k], b[k] = a[k - 1], b[k - 1]
                continue
            previous = signature
            caps = person.capsules_at(k * step_s)
            for g, name in enumerate(names):
                a[k, g], b[k, g], radius[g] = caps[name]
        return cls(float(step_s), a, b, radius)

    def index(self, t: np.ndarray | float) -> np.ndarray:
        """Sample indices of the times ``t`` [s] (nearest sample; held after the end)."""
        return np.clip(np.rint(np.asarray(t, dtype=float) / self.step_s), 0, self.a.shape[0] - 1).astype(int)

    def at(self, t: np.ndarray | float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Capsules (A, B, r) at time(s) ``t`` [s]: shapes (..., G, 3), (..., G, 3), (G,)."""
        k = self.index(t)
        return self.a[k], self.b[k], self.radius


def capsule_margins(
    points: np.ndarray, a: np.ndarray, b: np.ndarray, radius: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    r"""Signed distance of every point to every capsule, and the outward unit normals.

    .. math:: d_{kg} = \|P_k - C_{kg}\| - r_g,\qquad n_{kg} = \frac{P_k - C_{kg}}{\|P_k - C_{kg}\|}

    with :math:`C_{kg}` the closest point of segment g to :math:`P_k`. :math:`\partial d/\partial P
    = n^T` (the closest point's own motion does not change d to first order). Leading batch
    dimensions (e.g. one set of points and capsules per knot) broadcast.

    Args:
        points: Query points [m]. Shape (..., K, 3).
        a: Segment starts [m]. Shape (..., G, 3).
        b: Segment ends [m]. Shape (..., G, 3).
        radius: Radii [m]. Shape (G,).

    Returns:
        Distances [m] (negative inside a capsule), shape (..., K, G); normals, shape (..., K, G, 3).
    """
    ab = b - a
    ab2 = np.einsum("...gi,...gi->...g", ab, ab)
    ap = points[..., :, None, :] - a[..., None, :, :]
    safe = np.where(ab2 > 0.0, ab2, 1.0)
    tpar = np.clip(np.einsum("...kgi,...gi->...kg", ap, ab) / safe[..., None, :], 0.0, 1.0)
    tpar = tpar * (ab2 > 0.0)[..., None, :]
    diff = ap - tpar[..., None] * ab[..., None, :, :]
    norm = np.sqrt(np.einsum("...kgi,...kgi->...kg", diff, diff))
    normal = diff / np.maximum(norm, 1e-12)[..., None]
    return norm - radius, normal


# ------------------------------------------------------------------------------------ controller


@dataclass
class _Linearization:
    """Everything the QP needs about one configuration of the rollout."""

    cp_pos: np.ndarray  # (K, 3)
    cp_jac: np.ndarray  # (K, 3, n)
    sigma: np.ndarray  # (M,) set-task values
    sigma_jac: np.ndarray  # (M, n)


class ClairvoyantOracle:
    """The receding-horizon optimiser of the module docstring, behind the loop's solver interface.

    Args:
        robot: The arm (its limits; a private copy computes the rollout kinematics, so the loop's
            kinematics snapshot is never made stale).
        hierarchy: The scenario's tasks: obstacle tasks give the control points and their safety
            thresholds, every other set task (joint limits, walls) a constraint.
        track: The person's future capsules.
        settings: ``[oracle]``.
        clock: Absolute simulation time [s] (the person's clock).
    """

    name = ORACLE_METHOD

    def __init__(
        self,
        robot: robots.Robot,
        hierarchy: Hierarchy,
        track: PersonTrack,
        settings: OracleConfig,
        clock: Callable[[], float],
    ) -> None:
        self._robot = robots.Robot(robot.name, robot.spec)
        self._v_max = robot.v_max.copy()
        self._q_lower = robot.q_lower.copy()
        self._q_upper = robot.q_upper.copy()
        obstacles = [t for t in hierarchy.set_tasks if isinstance(t, ObstacleDistanceTask)]
        if not obstacles:
            raise ValueError("the oracle needs obstacle distance tasks (control points and their thresholds)")
        self.control_points = tuple(t.frame for t in obstacles)
        self.safety_m = np.array([t.thresholds.safety_lower for t in obstacles])
        self._constraints: list[SetTask] = [t for t in hierarchy.set_tasks if not isinstance(t, ObstacleDistanceTask)]
        self._lower = np.array([t.thresholds.safety_lower for t in self._constraints])
        self._upper = np.array([t.thresholds.safety_upper for t in self._constraints])
        self._track = track
        self._settings = settings
        self._clock = clock
        self.n = robot.nq
        self.knots = max(1, int(math.ceil(settings.horizon_s / settings.knot_s - 1e-9)))
        self.h = float(settings.knot_s)
        self._plan = np.zeros((self.knots, self.n))
        self._plan_t = -math.inf
        self.qp_calls = 0
        self.replans = 0
        self.qp_failures = 0

    # -- the loop's interface ------------------------------------------------------------------
    def solve(self, hierarchy: Hierarchy, kin: Kinematics, dt: float) -> StepResult:
        """The plan's velocity for now; re-optimised every ``replan_period_s``."""
        start = time.perf_counter()
        t = self._clock()
        if t - self._plan_t >= self._settings.replan_period_s - 1e-9:
            self._replan(np.array(kin.q, dtype=float), t)
        k = min(int((t - self._plan_t + 1e-9) // self.h), self.knots - 1)
        qdot = np.clip(self._plan[k], -self._v_max, self._v_max)
        return StepResult(qdot, SolveStatus.OK, solve_time_s=time.perf_counter() - start)

    # -- optimisation ---------------------------------------------------------------------------
    def _replan(self, q0: np.ndarray, t: float) -> None:
        self.replans += 1
        elapsed = 0 if not math.isfinite(self._plan_t) else int((t - self._plan_t + 1e-9) // self.h)
        shifted = np.zeros_like(self._plan)
        if elapsed < self.knots:
            shifted[: self.knots - elapsed] = self._plan[elapsed:]
        self._plan_t = t
        times = t + self.h * np.arange(1, self.knots + 1)
        cap = self._settings.margin_cap_m
        hold = np.zeros_like(self._plan)
        hold_value, hold_margin = self._true_objective(q0, hold, times)
        if hold_margin >= cap - 1e-9 and hold_value >= cap * (1.0 + self._settings.secondary_weight) - 1e-9:
            self._plan = hold
            return
        best, best_value = hold, hold_value
        warm_value, _ = self._true_objective(q0, shifted, times)
        if warm_value > best_value:
            best, best_value = shifted, warm_value
        plan = best.copy()
        for _ in range(self._settings.sqp_iterations):
            candidate = self._sqp_step(q0, plan, times)
            if candidate is None:
                break
            value, _ = self._true_objective(q0, candidate, times)
            plan = candidate
            if value > best_value:
                best, best_value = candidate, value
        self._plan = best

    def _rollout(self, q0: np.ndarray, plan: np.ndarray) -> np.ndarray:
        """Configurations at knots 1..N [rad]. Shape (N, n)."""
        return q0[None, :] + self.h * np.cumsum(plan, axis=0)

    def _linearize(self, q: np.ndarray) -> _Linearization:
        kin = self._robot.kinematics(q)
        pos = np.array([kin.frame_position(cp) for cp in self.control_points])
        jac = np.array([kin.position_jacobian(cp) for cp in self.control_points])
        m = len(self._constraints)
        sigma = np.empty(m)
        sigma_jac = np.empty((m, self.n))
        for k, task in enumerate(self._constraints):
            value, row = task.compute_value_and_jacobian(kin)
            sigma[k] = value
            sigma_jac[k] = np.asarray(row, dtype=float).reshape(-1)
        return _Linearization(pos, jac, sigma, sigma_jac)

    def _margins(self, cp_pos: np.ndarray, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Margins to the safety thresholds (K, G) and normals (K, G, 3) at time ``t``."""
        a, b, r = self._track.at(t)
        dist, normal = capsule_margins(cp_pos, a, b, r)
        return dist - self.safety_m[:, None], normal

    def _set_violation(self, sigma: np.ndarray) -> float:
        """Largest distance of a set task past its safety thresholds (0 inside) [task unit]."""
        if sigma.size == 0:
            return 0.0
        return max(0.0, float(np.max(np.maximum(self._lower - sigma, sigma - self._upper))))

    def _true_objective(self, q0: np.ndarray, plan: np.ndarray, times: np.ndarray) -> tuple[float, float]:
        """Objective of ``plan`` with exact distances and task values; and its minimum margin [m]."""
        cap = self._settings.margin_cap_m
        if not np.any(plan):
            lins = [self._linearize(q0)] * self.knots  # holding still: one configuration
            qs = np.repeat(q0[None, :], self.knots, axis=0)
        else:
            qs = self._rollout(q0, plan)
            lins = [self._linearize(q) for q in qs]
        pos = np.stack([lin.cp_pos for lin in lins])  # (N, K, 3)
        a, b, r = self._track.at(times)
        margin = capsule_margins(pos, a, b, r)[0] - self.safety_m[None, :, None]  # (N, K, G)
        knot_min = np.minimum(cap, margin.min(axis=(1, 2)))
        violation = max(self._set_violation(lin.sigma) for lin in lins)
        with np.errstate(invalid="ignore"):
            past = np.maximum(np.nan_to_num(self._q_lower - qs, nan=0.0), np.nan_to_num(qs - self._q_upper, nan=0.0))
        violation = max(violation, float(np.max(past)), 0.0)
        mu = self._settings.secondary_weight
        overall = float(knot_min.min())
        value = overall + mu * float(knot_min.mean()) - _SLACK_WEIGHT * violation
        return value, overall

    def _sqp_step(self, q0: np.ndarray, plan: np.ndarray, times: np.ndarray) -> np.ndarray | None:
        """One linearise-and-solve iteration around ``plan``; None when the backend fails."""
        n, N, h = self.n, self.knots, self.h
        cfg = self._settings
        cap = cfg.margin_cap_m
        nu = N * n
        i_s, i_w = nu + N, nu + N + 1
        nv = nu + N + 2
        rows: list[np.ndarray] = []
        rhs: list[float] = []
        qbar = self._rollout(q0, plan)
        v_reach = h * np.cumsum(np.ones(N))[:, None] * self._v_max[None, :]  # largest |q_i − q0| (N, n)
        for i in range(N):
            lin = self._linearize(qbar[i])
            offset = q0 - qbar[i]  # q_i = q0 + h Σ_{j<i} u_j ⇒ q_i − q̄_i = offset + h Σ u_j
            margin, normal = self._margins(lin.cp_pos, times[i])
            keep = np.argwhere(margin < cap + _ROW_CUTOFF_M)
            for c, g in keep:
                grad = normal[c, g] @ lin.cp_jac[c]  # ∂d/∂q (n,)
                row = np.zeros(nv)
                for j in range(i + 1):
                    row[j * n : (j + 1) * n] = -h * grad
                row[nu + i] = 1.0
                rows.append(row)
                rhs.append(float(margin[c, g] + grad @ offset))
            row = np.zeros(nv)  # s ≤ s_i
            row[i_s], row[nu + i] = 1.0, -1.0
            rows.append(row)
            rhs.append(0.0)
            reach = np.abs(lin.sigma_jac) @ v_reach[i]
            for k in range(len(self._constraints)):
                a_k = lin.sigma_jac[k]
                base = float(lin.sigma[k] + a_k @ offset)  # σ at u = 0 (linearised)
                for sign, bound in ((-1.0, self._lower[k]), (1.0, self._upper[k])):
                    if not math.isfinite(bound) or sign * (bound - base) > reach[k] + 1e-9:
                        continue  # cannot bind within the horizon
                    row = np.zeros(nv)
                    for j in range(i + 1):
                        row[j * n : (j + 1) * n] = sign * h * a_k
                    row[i_w] = -1.0
                    rows.append(row)
                    rhs.append(float(sign * (bound - base)))
            for jnt in range(n):
                for sign, limit in ((1.0, self._q_upper[jnt]), (-1.0, self._q_lower[jnt])):
                    if not math.isfinite(limit):
                        continue
                    room = sign * (limit - q0[jnt])
                    if room > v_reach[i, jnt] + 1e-9:
                        continue
                    row = np.zeros(nv)
                    for j in range(i + 1):
                        row[j * n + jnt] = sign * h
                    rows.append(row)
                    rhs.append(max(room, 0.0))  # already past the limit: do not go further
        G = np.array(rows)
        hvec = np.array(rhs)
        P = np.full(nv, _TINY)
        P[:nu] = _EFFORT_WEIGHT
        P[i_w] = 1.0
        c = np.zeros(nv)
        c[i_s] = -1.0
        c[nu : nu + N] = -cfg.secondary_weight / N
        c[i_w] = _SLACK_WEIGHT
        u0 = plan.reshape(-1)
        v = np.tile(self._v_max, N)
        lb = np.concatenate([np.maximum(-v, u0 - cfg.trust_region_rad_s), np.full(N + 1, -5.0), [0.0]])
        ub = np.concatenate([np.minimum(v, u0 + cfg.trust_region_rad_s), np.full(N + 1, cap), [10.0]])
        problem = qpsolvers.Problem(np.diag(P), c, G, hvec, lb=lb, ub=ub)
        self.qp_calls += 1
        try:
            solution = qpsolvers.solve_problem(problem, solver=cfg.solver)
        except (ValueError, ArithmeticError, qpsolvers.QPError) as exc:  # a failed QP: keep the best plan
            log.debug("oracle QP raised %s", exc)
            solution = None
        x = None if solution is None or not solution.found else solution.x
        if x is None or not np.all(np.isfinite(x)):
            self.qp_failures += 1
            return None
        return np.clip(x[:nu].reshape(N, n), -self._v_max, self._v_max)


# ------------------------------------------------------------------------------------ one run


@dataclass
class OracleRun:
    """The oracle on one scenario.

    Attributes:
        entry: The run's ``summary.json["oracle"]`` (DESIGN §7: ``min_distance_m``,
            ``held_safety``, and extras).
        steps: The oracle's per-step table (None when read from a cache without steps).
    """

    entry: dict[str, Any]
    steps: pd.DataFrame | None = None


def _control_point_tasks(hierarchy: Hierarchy) -> list[ObstacleDistanceTask]:
    return [t for t in hierarchy.set_tasks if isinstance(t, ObstacleDistanceTask)]


def oracle_key(config: Config, robot: robots.Robot) -> str:
    """Cache key of the oracle of a *realized* scenario: everything its result depends on."""
    sc = config.scenario
    data = {
        "version": ORACLE_VERSION,
        "robot": robot.name,
        "scenario": {
            k: getattr(sc, k)
            for k in (
                "duration_s",
                "time_scale",
                "control_rate_hz",
                "simulation",
                "drive",
                "drive_bandwidth_rad_s",
                "start_q",
            )
        },
        "person": [f.model_dump(mode="json") for f in config.person.keyframes],
        "levels": config.hierarchy_description(),
        "oracle": config.oracle.model_dump(mode="json", exclude={"enabled", "avoidable_only", "max_draws"}),
    }
    text = json.dumps(to_jsonable(data), sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:20]


def run_oracle(config: Config, robot: robots.Robot, stop_at_violation: bool = False) -> OracleRun:
    """Drive the plant of ``config`` (realized) with the oracle for the whole run.

    Args:
        config: A realized scenario (scripted, or random after
            :func:`compare.campaign.random_scenario.realize`).
        robot: The arm.
        stop_at_violation: Stop as soon as a control point is past its safety threshold (by more
            than the metrics' tolerance): enough to reject a draw of the avoidable family.

    Returns:
        The entry (``min_distance_m``, ``held_safety``, ``safety_threshold_m``, ``horizon_s``,
        ``stopped_early``, joint-limit and wall margins, ``wall_time_s``, QP counts) and the steps.
    """
    from compare.analysis.metrics import VIOLATION_TOLERANCE
    from compare.run import loop_setup, run_meta

    start = time.perf_counter()
    sc = config.scenario.model_copy(update={"sensing": "geometric"})  # the oracle senses nothing
    config = config.model_copy(update={"scenario": sc})
    hierarchy = config.build_hierarchy(robot)
    tasks = _control_point_tasks(hierarchy)
    q0 = np.array(sc.start_q) if sc.start_q is not None else robot.home.copy()
    sim = build_simulation(config, robot, q0)
    settings_o = config.oracle
    track = PersonTrack.from_person(sim.person, sc.sim_time_s + settings_o.horizon_s + 1.0, sc.dt)
    oracle = ClairvoyantOracle(robot, hierarchy, track, settings_o, sim.io.now)
    schedule, settings = loop_setup(config, robot.frame_position(q0, robot.ee_frame))
    thresholds = {t.frame: t.thresholds.safety_lower for t in tasks}
    state = {"min_margin": math.inf}

    def truth(kin: Kinematics) -> dict[str, float]:
        d = sim.truth(kin)
        for frame, thr in thresholds.items():
            state["min_margin"] = min(state["min_margin"], d.get(frame, math.inf) - thr)
        return d

    def keep_going() -> bool:
        return not (stop_at_violation and state["min_margin"] < -VIOLATION_TOLERANCE)

    try:
        out = run_loop(sim.io, robot, hierarchy, oracle, schedule, settings, None, truth, on_step=keep_going)
    finally:
        sim.close()
    meta = run_meta(config, ORACLE_METHOD, hierarchy, robot, out, "none (clairvoyant)")
    summary = compute_summary(out.steps, meta)
    dists = [d for d in summary["min_obstacle_distance_m"] if d is not None]
    obstacles = summary.get("obstacles") or {}
    stopped = out.sim_time_s < sc.sim_time_s - 1.5 * sc.dt
    entry = {
        "min_distance_m": min(dists) if dists else None,
        "held_safety": bool(not obstacles.get("violations")) and not stopped,
        "safety_threshold_m": float(min(thresholds.values())),
        "safety_margin_min": obstacles.get("safety_margin_min"),
        "min_distance_per_control_point_m": dict(
            zip(summary["control_points"], summary["min_obstacle_distance_m"], strict=True)
        ),
        "joint_limits_margin_min": (summary.get("joint_limits") or {}).get("safety_margin_min"),
        "walls_margin_min": (summary.get("walls") or {}).get("safety_margin_min"),
        "horizon_s": settings_o.horizon_s,
        "solver": settings_o.solver,
        "stopped_early": stopped,
        "sim_time_s": out.sim_time_s,
        "wall_time_s": time.perf_counter() - start,
        "replans": oracle.replans,
        "qp_calls": oracle.qp_calls,
        "qp_failures": oracle.qp_failures,
        "key": oracle_key(config, robot),
    }
    return OracleRun(to_jsonable(entry), out.steps)


def cached_oracle(
    config: Config, robot: robots.Robot, cache_dir: Path | None, stop_at_violation: bool = False
) -> OracleRun:
    """:func:`run_oracle`, read from ``cache_dir/<key>.json`` when it was computed before.

    A result computed with ``stop_at_violation`` that stopped early is only reused by a caller
    that also accepts a stopped run (both say ``held_safety = false``; the full run has the true
    minimum distance).
    """
    key = oracle_key(config, robot)
    path = None if cache_dir is None else Path(cache_dir) / f"{key}.json"
    if path is not None and path.is_file():
        try:
            entry = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            entry = None
        if entry is not None and (stop_at_violation or not entry.get("stopped_early")):
            entry["cached"] = True
            return OracleRun(entry)
    result = run_oracle(config, robot, stop_at_violation)
    result.entry["cached"] = False
    if path is not None:
        from compare.analysis.results import write_json_atomic

        path.parent.mkdir(parents=True, exist_ok=True)
        write_json_atomic(path, {k: v for k, v in result.entry.items() if k != "cached"})
        if config.oracle.keep_steps and result.steps is not None:
            result.steps.to_parquet(path.with_suffix(".parquet"), index=False)
    return result

r"""A greedy preview policy: each step, the joint velocity that best keeps the arm away from where the person will be.

One of the verdict's witnesses (:mod:`compare.campaign.verdict`). Like the clairvoyant oracle
(:mod:`compare.campaign.oracle`) it knows the scripted person's future, has no mission, and
drives the same plant under the same limits; unlike it, it plans nothing: at every control step
it solves one small QP over the joint velocity :math:`\dot q` and acts on it at once.

**Formulation.** At time :math:`t`, with :math:`m_{c,g}(q, t')` the margin of control point c to
its safety threshold against the person's capsule g at time :math:`t'` (:math:`m = d -
\sigma_s`) and the preview instants :math:`t_j = t + \Delta t + j h` (j = 0..J, :math:`J h =
\tau`, the preview),

.. math::
    \max_{\dot q,\,s,\,w}\ s - \frac{\epsilon}{2}\|\dot q\|^2 - \rho w
    \quad\text{s.t.}\quad
    \begin{cases}
      s \le m_{c,g}(q, t_j) + H_j\, n_{c,g}^T J_c\, \dot q,\ \ s \le \bar m
        & \text{(every row with } m_{c,g} < \bar m + 0.3\text{ m)}\\
      -\frac{\sigma_k - \sigma_{k,l} - b}{T} - w \le J_k \dot q \le \frac{\sigma_{k,u} - b - \sigma_k}{T} + w
        & \text{(every other set task, and the joint position limits)}\\
      |\dot q| \le \dot q_{max},\ w \ge 0
    \end{cases}

with :math:`H_j = \min(\Delta t + j h, H_{max})`: the margin at a preview instant after moving
at :math:`\dot q` until then (at most :math:`H_{max}`, the horizon over which one linearisation
is trusted). The cap :math:`\bar m` makes holding still optimal when every previewed margin is
already :math:`\bar m` or more; the velocity damper on the other set tasks (time constant T,
buffer b, slack w at weight ρ) keeps joint limits and walls with the plant's lag. τ = 0 is the
purely reactive max-min policy.

A run of this policy that keeps every threshold is a witness like the oracle's; one that does
not proves nothing.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import qpsolvers

import robots
from compare.sensing.person_track import PersonTrack, capsule_margins
from robots import Kinematics
from tpik.hierarchy import Hierarchy
from tpik.step_result import SolverBase, SolveStatus, StepResult
from tpik.tasks import ObstacleDistanceTask, SetTask

log = logging.getLogger(__name__)

_ROW_CUTOFF_M = 0.3  # distance rows kept when the margin is below the cap + this [m]
_EFFORT_WEIGHT = 1e-3  # ε [1/(rad/s)²]
_SLACK_WEIGHT = 100.0  # ρ per task unit
_TINY = 1e-6  # keeps the Hessian positive definite for the QP backends


@dataclass(frozen=True)
class PreviewSettings:
    r"""Settings of :class:`PreviewPolicy`.

    Attributes:
        preview_s: τ: how far ahead the person is looked at [s] (0: reactive).
        sample_s: h: spacing of the preview instants [s].
        velocity_horizon_s: :math:`H_{max}` [s].
        margin_cap_m: :math:`\bar m` [m].
        damper_time_s: T of the set-task velocity damper [s].
        buffer: b, kept inside every other set task's safety threshold [task unit: m or rad].
        solver: qpsolvers backend.
    """

    preview_s: float = 1.0
    sample_s: float = 0.1
    velocity_horizon_s: float = 0.2
    margin_cap_m: float = 0.25
    damper_time_s: float = 0.05
    buffer: float = 0.003
    solver: str = "daqp"


class PreviewPolicy(SolverBase):
    """The policy of the module docstring, behind the loop's solver interface.

    Args:
        robot: The arm (velocity and position limits).
        hierarchy: The scenario's tasks: obstacle tasks give the control points and their safety
            thresholds, every other set task (joint limits, walls) a constraint.
        track: The person's future capsules.
        settings: :class:`PreviewSettings`.
        clock: Absolute simulation time [s] (the person's clock).
        name: Name in logs and tables.
    """

    def __init__(
        self,
        robot: robots.Robot,
        hierarchy: Hierarchy,
        track: PersonTrack,
        settings: PreviewSettings,
        clock: Callable[[], float],
        name: str = "preview",
    ) -> None:
        obstacles = [t for t in hierarchy.set_tasks if isinstance(t, ObstacleDistanceTask)]
        if not obstacles:
            raise ValueError("a preview policy needs obstacle distance tasks (control points and their thresholds)")
        self.name = name
        self.control_points = tuple(t.frame for t in obstacles)
        self.safety_m = np.array([t.thresholds.safety_lower for t in obstacles])
        self._constraints: list[SetTask] = [t for t in hierarchy.set_tasks if not isinstance(t, ObstacleDistanceTask)]
        self._lower = np.array([t.thresholds.safety_lower for t in self._constraints])
        self._upper = np.array([t.thresholds.safety_upper for t in self._constraints])
        self._v_max = robot.v_max.copy()
        self._q_lower = robot.q_lower.copy()
        self._q_upper = robot.q_upper.copy()
        self._track = track
        self._settings = settings
        self._clock = clock
        self._samples = 1 + int(round(settings.preview_s / settings.sample_s)) if settings.preview_s > 0 else 1
        self.qp_calls = 0
        self.qp_failures = 0

    def stats(self) -> dict[str, int]:
        """Work done so far: QP calls and failures."""
        return {"qp_calls": self.qp_calls, "qp_failures": self.qp_failures}

    def solve(self, hierarchy: Hierarchy, kin: Kinematics, dt: float) -> StepResult:
        """This step's joint velocity (zero when the QP backend fails)."""
        start = time.perf_counter()
        self.qp_calls += 1
        qdot = self._qp(kin, dt)
        status = SolveStatus.OK
        if qdot is None:
            self.qp_failures += 1
            qdot, status = np.zeros(kin.nq), SolveStatus.FAILED
        return StepResult(qdot, status, solve_time_s=time.perf_counter() - start)

    def _qp(self, kin: Kinematics, dt: float) -> np.ndarray | None:
        cfg = self._settings
        n = kin.nq
        nv = n + 2
        i_s, i_w = n, n + 1
        cap = cfg.margin_cap_m
        pos = np.array([kin.frame_position(cp) for cp in self.control_points])
        jac = np.array([kin.position_jacobian(cp) for cp in self.control_points])
        lead = dt + cfg.sample_s * np.arange(self._samples)
        a, b, r = self._track.at(self._clock() + lead)  # (J, G, 3)
        dist, normal = capsule_margins(np.broadcast_to(pos, (len(lead), *pos.shape)), a, b, r)
        margin = dist - self.safety_m[None, :, None]  # (J, K, G)
        j, c, g = np.nonzero(margin < cap + _ROW_CUTOFF_M)
        near = np.zeros((len(j), nv))
        hold = np.minimum(lead[j], cfg.velocity_horizon_s)  # H_j
        near[:, :n] = -hold[:, None] * np.einsum("ri,rin->rn", normal[j, c, g], jac[c])
        near[:, i_s] = 1.0
        rows: list[np.ndarray] = [near]
        rhs: list[np.ndarray] = [margin[j, c, g]]
        tau = cfg.damper_time_s
        for k, task in enumerate(self._constraints):
            sigma, grad = task.compute_value_and_jacobian(kin)
            grad = np.asarray(grad, dtype=float).reshape(-1)
            for sign, bound in ((-1.0, self._lower[k]), (1.0, self._upper[k])):
                if math.isfinite(bound):  # sign·J q̇ ≤ sign·(bound − sign·b − σ)/T + w
                    row = np.zeros((1, nv))
                    row[0, :n] = sign * grad
                    row[0, i_w] = -1.0
                    rows.append(row)
                    rhs.append(np.array([sign * (bound - sign * cfg.buffer - float(sigma)) / tau]))
        q = np.asarray(kin.q, dtype=float)
        lb = -self._v_max.copy()
        ub = self._v_max.copy()
        finite_lo, finite_hi = np.isfinite(self._q_lower), np.isfinite(self._q_upper)
        lb[finite_lo] = np.maximum(lb[finite_lo], np.minimum((self._q_lower - q)[finite_lo] / tau, 0.0))
        ub[finite_hi] = np.minimum(ub[finite_hi], np.maximum((self._q_upper - q)[finite_hi] / tau, 0.0))
        P = np.full(nv, _TINY)
        P[:n] = _EFFORT_WEIGHT
        cost = np.zeros(nv)
        cost[i_s] = -1.0
        cost[i_w] = _SLACK_WEIGHT
        G = np.concatenate(rows)
        problem = qpsolvers.Problem(
            np.diag(P),
            cost,
            G if len(G) else None,
            np.concatenate(rhs) if len(G) else None,
            lb=np.concatenate([lb, [-5.0, 0.0]]),
            ub=np.concatenate([ub, [cap, 10.0]]),
        )
        try:
            solution = qpsolvers.solve_problem(problem, solver=cfg.solver)
        except (ValueError, ArithmeticError, qpsolvers.QPError) as exc:
            log.debug("preview QP raised %s", exc)
            return None
        if not solution.found or solution.x is None or not np.all(np.isfinite(solution.x)):
            return None
        return np.clip(solution.x[:n], -self._v_max, self._v_max)

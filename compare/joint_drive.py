"""Joint drives of the simulated arm: how a velocity command becomes joint torque.

The solvers command joint velocities (DESIGN §4). What the arm does with them is the plant's
business, and it decides how far a held constraint is overshot in ``dynamic`` simulation:

* ``servo`` — the MJCF's own actuators: one P-only velocity servo per joint,
  τ_i = k_v (q̇_c,i − q̇_i), with passive gravity compensation. Each joint lags by M_ii / k_v
  (1–10 ms on this arm), runs k_v / (k_v + d) ≈ 1.2 % slow against the joint damping d, and is
  pushed by the other joints' inertial and Coriolis torques (τ / k_v of velocity error).
  An end effector sliding fast along a held wall drifts into it until the task's gain K·e
  balances that drift: 1–5 mm in about 3 % of the hard random runs (docs/benchmarks.md).
* ``decoupled`` (default) — a drive that cancels the arm's dynamics, the assumption every
  velocity-level IK scheme (and the paper's eq. 1–2) makes of its low-level controller:

      τ = M(q) λ (q̇_c − q̇) + c(q, q̇) + D q̇,     clipped to the joint torque limits,

  with M the joint-space inertia (plus h D, h the physics step: ``implicitfast`` integrates the
  damping implicitly, dividing by M + h D), c the Coriolis/centrifugal (and any gravity that the passive
  ``gravcomp`` does not cancel) forces, D the joint damping and λ the drive bandwidth [rad/s].
  Every joint then follows q̈ = λ (q̇_c − q̇): the same first-order lag 1/λ on every joint,
  independent of posture and of the other joints, with no steady-state error (per physics step
  h the velocity error shrinks by 1 − λh). At a torque limit the acceleration demand is scaled
  down for all joints together (:meth:`DecoupledVelocityDrive.torque`), so the joints stay
  decoupled. The default λ = 100 rad/s (10 ms) is no faster than the slowest servo joint above.

The drive is evaluated at the start of every physics step (``mj_step1`` → torque →
``mj_step2``), so M and c are those of the state being integrated.
"""

from __future__ import annotations

from typing import Literal

import mujoco
import numpy as np

DriveKind = Literal["decoupled", "servo"]

#: Largest λ·timestep: the explicit first-order update q̇ += λ dt (q̇_c − q̇) is monotone below 1.
MAX_BANDWIDTH_TIMESTEP = 0.5


class DecoupledVelocityDrive:
    """Inverse-dynamics velocity drive of the first ``nq`` joints (see the module docstring).

    Args:
        model: Scene model to be stepped; the arm's joints are its first ``nq`` DoFs. Its
            actuators are disabled here (``mjDSBL_ACTUATION``): the drive replaces the MJCF's
            velocity servos, so pass a model of your own (``SimRobotIO`` passes a copy).
        nq: Number of arm joints.
        bandwidth_rad_s: λ [rad/s]; the joint velocity's time constant is 1/λ.

    Raises:
        ValueError: λ ≤ 0, or λ·timestep above :data:`MAX_BANDWIDTH_TIMESTEP` (the explicit
            update would overshoot the command).
    """

    def __init__(self, model: mujoco.MjModel, nq: int, bandwidth_rad_s: float) -> None:
        step = float(model.opt.timestep)
        if not bandwidth_rad_s > 0.0 or bandwidth_rad_s * step > MAX_BANDWIDTH_TIMESTEP:
            raise ValueError(
                f"drive bandwidth must be in (0, {MAX_BANDWIDTH_TIMESTEP / step:g}] rad/s for the "
                f"model's {step * 1e3:g} ms timestep, got {bandwidth_rad_s!r}"
            )
        self.nq = nq
        self.bandwidth_rad_s = float(bandwidth_rad_s)
        n = nq
        self._ctrl_lo = model.actuator_ctrlrange[:n, 0].copy()
        self._ctrl_hi = model.actuator_ctrlrange[:n, 1].copy()
        limited = model.jnt_actfrclimited[:n].astype(bool)
        self._tau_max = np.where(limited, np.abs(model.jnt_actfrcrange[:n, 1]), np.inf)
        self._damping = model.dof_damping[:n].copy()
        self._mass = np.zeros((model.nv, model.nv))
        model.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_ACTUATION

    def torque(self, model: mujoco.MjModel, data: mujoco.MjData, command: np.ndarray) -> np.ndarray:
        """τ [N·m] for ``command`` [rad/s] at ``data``'s state (after ``mj_step1``).

        The command is clipped to the velocity limits (the servos' ``ctrlrange``) first, as the
        servo drive's MuJoCo actuators do. When τ would exceed a joint's torque limit, the
        acceleration demand a = λ (q̇_c − q̇) is scaled down as a whole, τ = M s a + c + D q̇
        with the largest s ∈ [0, 1] that fits every limit: the joints slow down together and a
        joint commanded to stay still still gets zero acceleration. Only when c + D q̇ alone
        exceeds a limit (s = 0) is τ clipped per joint.
        """
        n = self.nq
        mujoco.mj_fullM(model, data, self._mass)
        qd = data.qvel[:n]
        qd_c = np.clip(command, self._ctrl_lo, self._ctrl_hi)
        hold = data.qfrc_bias[:n] - data.qfrc_gravcomp[:n] + self._damping * qd
        push = self._inertia(model) @ (self.bandwidth_rad_s * (qd_c - qd))
        tau = hold + push
        over = np.abs(tau) > self._tau_max
        if not over.any():
            return tau
        room = np.where(push > 0.0, self._tau_max - hold, -self._tau_max - hold)
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = np.where(over & (push != 0.0), room / push, np.inf)
        scale = float(np.clip(np.min(ratio), 0.0, 1.0))
        return np.clip(hold + scale * push, -self._tau_max, self._tau_max)

    def _inertia(self, model: mujoco.MjModel) -> np.ndarray:
        """M + h D: the inertia the ``implicitfast`` step divides by (it treats D implicitly)."""
        n = self.nq
        return self._mass[:n, :n] + np.diag(model.opt.timestep * self._damping)

    def step(self, model: mujoco.MjModel, data: mujoco.MjData, command: np.ndarray, substeps: int) -> None:
        """Advance ``substeps`` physics steps, recomputing the torque before each."""
        n = self.nq
        for _ in range(substeps):
            mujoco.mj_step1(model, data)
            data.qfrc_applied[:n] = self.torque(model, data, command)
            mujoco.mj_step2(model, data)

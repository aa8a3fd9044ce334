"""Joint drives of the simulated arm: how a velocity command becomes joint torque.

The solvers command joint velocities (docs/design.md §4). What the arm does with them is the plant's
business, and it decides how far a held constraint is overshot in ``dynamic`` simulation:

* ``servo`` — the MJCF's own actuators: one P-only velocity servo per joint,
  τ_i = k_v (q̇_c,i − q̇_i), with passive gravity compensation. Each joint lags by M_ii / k_v
  (1–10 ms on this arm), runs k_v / (k_v + d) ≈ 1.2 % slow against the joint damping d, and is
  pushed by the other joints' inertial and Coriolis torques (τ / k_v of velocity error).
  An end effector sliding fast along a held wall drifts into it until the task's gain K·e
  balances that drift: 1–5 mm in about 3 % of the hard random runs (docs/benchmarks.md).
* ``decoupled`` (default) — a drive that cancels the arm's dynamics, the assumption every
  velocity-level IK scheme (and the paper's eqs. 1–2) makes of its low-level controller:

      τ = (M(q) + h D) λ (q̇_c − q̇) + c(q, q̇) + D q̇,     within the joint torque limits,

  with M the joint-space inertia, h the physics step (``implicitfast`` integrates the damping
  implicitly, i.e. divides by M + h D), c the Coriolis/centrifugal forces (and any gravity the
  passive ``gravcomp`` does not cancel), D the joint damping and λ the drive bandwidth [rad/s].
  Every joint then follows q̈ = λ (q̇_c − q̇): the same first-order lag 1/λ on every joint,
  independent of posture and of the other joints, with no steady-state error (per physics step
  the velocity error shrinks by 1 − λh). At a torque limit the acceleration demand is scaled
  down for all joints together (:meth:`DecoupledVelocityDrive.torque`), so the joints stay
  decoupled. The default λ = 100 rad/s (10 ms) is no faster than the slowest servo joint above.

The drive is evaluated at the start of every physics step (``mj_step1`` → torque →
``mj_step2``), so M and c are those of the state being integrated.
"""

from __future__ import annotations

from typing import Literal

import mujoco
import numba
import numpy as np

DriveKind = Literal["decoupled", "servo"]

#: Largest λ·h accepted: the update q̇ += λ h (q̇_c − q̇) per physics step h overshoots the command
#: from λh = 1 on; half of that keeps every joint's response monotone with a margin.
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
        ValueError: λ ≤ 0, or λ·timestep above :data:`MAX_BANDWIDTH_TIMESTEP`.
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
        self._step_s = step  # h: the λ bound above was checked against it
        n = nq
        self._ctrl_lo = model.actuator_ctrlrange[:n, 0].copy()
        self._ctrl_hi = model.actuator_ctrlrange[:n, 1].copy()
        limited = model.jnt_actfrclimited[:n].astype(bool)
        self._tau_max = np.where(limited, np.abs(model.jnt_actfrcrange[:n, 1]), np.inf)
        self._damping = model.dof_damping[:n].copy()
        self._mass = np.zeros((model.nv, model.nv))
        model.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_ACTUATION

    def step(self, model: mujoco.MjModel, data: mujoco.MjData, command: np.ndarray, substeps: int) -> None:
        """Advance ``substeps`` physics steps, recomputing the torque τ [N·m] before each.

        The command [rad/s] is clipped to the velocity limits (the servos' ``ctrlrange``) first,
        as the servo drive's MuJoCo actuators do. When τ would exceed a joint's torque limit, the
        acceleration demand a = λ (q̇_c − q̇) is scaled down as a whole, τ = (M + hD) s a + c + D q̇
        with the largest s ∈ [0, 1] that fits every limit: the joints slow down together and a
        joint commanded to stay still still gets zero acceleration. Only when c + D q̇ alone
        exceeds a limit (s = 0) is τ clipped per joint. The last sub-step's τ stays in
        ``data.qfrc_applied``.
        """
        qd_c = np.minimum(np.maximum(command, self._ctrl_lo), self._ctrl_hi)  # np.clip, without its overhead
        applied = data.qfrc_applied[: self.nq]
        # ``data``'s arrays are views of fixed MuJoCo buffers: looked up once, they serve every sub-step.
        qvel, bias, gravcomp, mass = data.qvel, data.qfrc_bias, data.qfrc_gravcomp, self._mass
        damping, h, lam, tau_max = self._damping, self._step_s, self.bandwidth_rad_s, self._tau_max
        step1, step2, full_mass = mujoco.mj_step1, mujoco.mj_step2, mujoco.mj_fullM
        for _ in range(substeps):
            step1(model, data)
            full_mass(model, data, mass)
            _drive_torque(qd_c, qvel, bias, gravcomp, mass, damping, h, lam, tau_max, applied)
            step2(model, data)


@numba.njit(cache=True, nogil=True)
def _drive_torque(
    qd_c: np.ndarray,
    qvel: np.ndarray,
    bias: np.ndarray,
    gravcomp: np.ndarray,
    mass: np.ndarray,
    damping: np.ndarray,
    h: float,
    lam: float,
    tau_max: np.ndarray,
    out: np.ndarray,
) -> None:
    """Torque into ``out``: hold + s·push, s the largest in [0, 1] within ±τ_max (see the module).

    hold = c + D q̇, push = (M + hD) λ (q̇_c − q̇).

    c = qfrc_bias − qfrc_gravcomp (the bias the passive gravity compensation leaves); the
    implicitfast step divides by M + hD, so (M + hD) a yields the acceleration a exactly.
    """
    n = qd_c.shape[0]
    acc = np.empty(n)
    for i in range(n):
        acc[i] = lam * (qd_c[i] - qvel[i])
    scale = 1.0
    hold = np.empty(n)
    push = np.empty(n)
    for i in range(n):
        p = h * damping[i] * acc[i]
        for j in range(n):
            p += mass[i, j] * acc[j]
        push[i] = p
        hold[i] = bias[i] - gravcomp[i] + damping[i] * qvel[i]
        t = hold[i] + p
        if t > tau_max[i] and p > 0.0:
            scale = min(scale, (tau_max[i] - hold[i]) / p)
        elif t < -tau_max[i] and p < 0.0:
            scale = min(scale, (-tau_max[i] - hold[i]) / p)
    scale = max(scale, 0.0)
    for i in range(n):
        out[i] = min(max(hold[i] + scale * push[i], -tau_max[i]), tau_max[i])

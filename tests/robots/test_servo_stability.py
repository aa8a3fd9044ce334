"""The velocity servos of the MJCF stay stable when their force saturates.

MuJoCo's ``implicitfast`` integrator treats a velocity servo's damping ``kv`` implicitly only
while the servo force is inside its ``forcerange`` (and the joint's ``actuatorfrcrange``); a
saturated servo is integrated explicitly. With 5 ms physics steps that explicit step was
unstable (``kv·dt/λ_min(M)`` ≈ 4 > 2): a command step of more than forcerange/kv started a
self-sustained ±limit cycle in which the joint no longer followed its command. In the hard
random campaign joint 6 drifted 37 mrad past its limit (seed 379) and the EE 57 mm past a wall
(seed 215) while the controllers commanded away from them.
"""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

import robots
from tests.conftest import random_configuration


def _servo_gains(model: mujoco.MjModel) -> np.ndarray:
    # velocity actuator: force = kv·ctrl − kv·q̇ (gainprm[0] = kv, biasprm[2] = −kv)
    return model.actuator_gainprm[:, 0].copy()


def test_physics_step_is_stable_for_a_saturated_servo(jaco: robots.Robot) -> None:
    """Explicit damping kv over the smallest inertia: dt·kv/λ_min(M) < 2 with a margin."""
    model = jaco.mj_model
    data = mujoco.MjData(model)
    kv = float(_servo_gains(model).max())
    rng = np.random.default_rng(9)
    M = np.zeros((model.nv, model.nv))
    lam_min = np.inf
    for _ in range(2000):
        data.qpos[:] = random_configuration(jaco, rng, inset=0.0)
        mujoco.mj_forward(model, data)
        mujoco.mj_fullM(model, data, M)
        lam_min = min(lam_min, float(np.linalg.eigvalsh(M)[0]))
    ratio = model.opt.timestep * kv / lam_min
    assert ratio < 1.8, f"timestep {model.opt.timestep} s: dt·kv/λ_min(M) = {ratio:.2f} (explicit limit 2)"


@pytest.mark.parametrize("joint", range(7))
def test_servo_reversal_past_the_force_limit_does_not_overshoot(jaco: robots.Robot, joint: int) -> None:
    """+v_max then −v_max on one joint (kv·2v_max is far past the force limit).

    A stable saturated servo accelerates at its force limit and settles on the command; the
    explicit overshoot at 5 ms reached 1.04 rad/s past the command (joint 7), 0.4–0.5 rad/s
    (joints 1, 5, 6): the start of the ±limit cycle.
    """
    model = jaco.mj_model
    data = mujoco.MjData(model)
    data.qpos[:] = jaco.home
    mujoco.mj_forward(model, data)
    v = float(jaco.v_max[joint])
    n = round(0.3 / model.opt.timestep)
    for sign in (1.0, -1.0):
        data.ctrl[:] = 0.0
        data.ctrl[joint] = sign * v
        qdot = np.empty(n)
        t = np.arange(1, n + 1) * model.opt.timestep
        for k in range(n):
            mujoco.mj_step(model, data)  # every physics step: the cycle alternates at that rate
            qdot[k] = data.qvel[joint]
        overshoot = float(np.max(sign * qdot - v))
        assert overshoot < 0.05, f"joint {joint + 1}: q̇ {overshoot:.3f} rad/s past the command {sign * v:+.3f}"
        off = np.abs(qdot - sign * v) > 0.02
        settle = float(t[np.flatnonzero(off)[-1]]) if off.any() else 0.0
        assert settle < 0.1, f"joint {joint + 1}: q̇ settles on the command after {settle:.3f} s"

"""A short headless MuJoCo run: the Jaco² end effector tracks one waypoint with CLIK (eq. 2).

Run with ``python -m compare.quickstart``. The full comparison harness lives in
:mod:`compare.cli`; this script only shows that the model, kinematics and tasks fit together.
"""

from __future__ import annotations

import mujoco
import numpy as np

import robots
from tpik.tasks import PositionTask


def main(duration_s: float = 4.0, dt: float = 0.01) -> float:
    """Track ``[0.3, 0.3, 0.5]`` m for ``duration_s`` of simulated time; return the final error [m]."""
    robot = robots.load("jaco2")
    model = mujoco.MjModel.from_xml_path(str(robot.spec.scene_file))
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, model.keyframe("home").id)
    task = PositionTask("ee", "end_effector", gain=1.5, target=np.array([0.3, 0.3, 0.5]))
    substeps = max(1, round(dt / model.opt.timestep))
    for step in range(round(duration_s / dt)):
        state = task.compute_state(robot.kinematics(data.qpos.copy()))
        # q̇ = J† (σ̇_d + K σ̃)  (paper eq. 2), scaled into the velocity limits.
        qdot = np.linalg.pinv(state.jacobian) @ (state.feedforward + task.gain * state.error)
        qdot *= min(1.0, float(np.min(robot.v_max / np.maximum(np.abs(qdot), 1e-12))))
        data.ctrl[:] = qdot
        mujoco.mj_step(model, data, nstep=substeps)
        if step % 100 == 0:
            print(f"t={step * dt:4.1f} s  EE error {np.linalg.norm(state.error) * 1000:7.1f} mm")
    final = float(np.linalg.norm(task.target - robot.frame_position(data.qpos.copy(), "end_effector")))
    print(f"final EE error after {duration_s:.1f} s: {final * 1000:.1f} mm")
    return final


if __name__ == "__main__":
    main()

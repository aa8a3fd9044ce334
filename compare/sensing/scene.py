"""The work-cell scene: where it is, how to load it, and the control points.

The robot's work cell (:meth:`robots.Robot.workcell_model`): the arm on its table + the
Kinect-like depth camera + the capsule person (mocap bodies), ``robots/workcell/``. World frame =
arm base frame. The control points are the frames of a hierarchy's obstacle tasks
(``compare.loop.closed_loop.control_points``), by default the robot's (``robot.control_points``).
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

import mujoco
import numpy as np

import robots
from robots import Kinematics


def workcell_path(robot: str = robots.DEFAULT_ROBOT) -> Path | None:
    """The robot's own work-cell MJCF, or None when it is composed from ``robots/workcell/``."""
    return robots.load(robot).spec.workcell


def load_workcell(robot: str = robots.DEFAULT_ROBOT) -> mujoco.MjModel:
    """Compile the work-cell scene (arm, table, depth camera, person)."""
    return robots.load(robot).workcell_model()


def make_data(model: mujoco.MjModel, q: np.ndarray | None = None, keyframe: str = "home") -> mujoco.MjData:
    """Data reset to ``keyframe`` (arm joints overridden by ``q`` [rad] if given), kinematics done."""
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, model.keyframe(keyframe).id)
    if q is not None:
        set_arm_configuration(model, data, q)
    mujoco.mj_forward(model, data)
    return data


def arm_qpos_addresses(model: mujoco.MjModel, prefix: str | None = None) -> np.ndarray:
    """Addresses in ``qpos`` of the arm joints, in joint order.

    Args:
        model: The work cell.
        prefix: Joint name prefix of the arm; None = the joints of the subtree holding the
            model's first joint (the arm: the person has none).
    """
    if prefix is None:
        arm = model.body_rootid[model.jnt_bodyid[0]]
        joints = [j for j in range(model.njnt) if model.body_rootid[model.jnt_bodyid[j]] == arm]
    else:
        joints = [j for j in range(model.njnt) if model.joint(j).name.startswith(prefix)]
    return model.jnt_qposadr[joints]


def set_arm_configuration(model: mujoco.MjModel, data: mujoco.MjData, q: np.ndarray) -> None:
    """Write the arm's joint positions [rad] (call ``mj_kinematics``/``mj_forward`` after)."""
    data.qpos[arm_qpos_addresses(model)] = q


def control_point_positions(kin: Kinematics, frames: Iterable[str]) -> dict[str, np.ndarray]:
    """Control point positions [m] in the base frame, by frame name."""
    return {name: kin.frame_position(name) for name in frames}

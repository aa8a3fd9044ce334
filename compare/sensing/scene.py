"""The work-cell scene: where it is, how to load it, and the control points.

``robots/kinova_j2s7s300/scene_workcell.xml`` = the arm on its table (``scene.xml``) + the
Kinect-like depth camera + the capsule person (mocap bodies). World frame = arm base frame.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

import mujoco
import numpy as np

import robots
from robots import Kinematics

CONTROL_POINTS = ("link_4", "link_6", "link_7")
"""Control point frames of the paper (origins of joints 4, 6, 7: elbow, wrist, hand)."""

WORKCELL_FILE = "scene_workcell.xml"


def workcell_path(robot: str = "jaco2") -> Path:
    """Path of the work-cell MJCF next to the robot's model file."""
    return robots.load(robot).spec.model_file.parent / WORKCELL_FILE


def load_workcell(robot: str = "jaco2") -> mujoco.MjModel:
    """Compile the work-cell scene (arm, table, depth camera, person)."""
    return mujoco.MjModel.from_xml_path(str(workcell_path(robot)))


def make_data(model: mujoco.MjModel, q: np.ndarray | None = None, keyframe: str = "home") -> mujoco.MjData:
    """Data reset to ``keyframe`` (arm joints overridden by ``q`` [rad] if given), kinematics done."""
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, model.keyframe(keyframe).id)
    if q is not None:
        set_arm_configuration(model, data, q)
    mujoco.mj_forward(model, data)
    return data


def arm_qpos_addresses(model: mujoco.MjModel, prefix: str = "j2s7s300_joint_") -> np.ndarray:
    """Addresses in ``qpos`` of the arm joints, in joint order."""
    joints = [j for j in range(model.njnt) if model.joint(j).name.startswith(prefix)]
    return model.jnt_qposadr[joints]


def set_arm_configuration(model: mujoco.MjModel, data: mujoco.MjData, q: np.ndarray) -> None:
    """Write the arm's joint positions [rad] (call ``mj_kinematics``/``mj_forward`` after)."""
    data.qpos[arm_qpos_addresses(model)] = q


def control_point_positions(kin: Kinematics, frames: Iterable[str] = CONTROL_POINTS) -> dict[str, np.ndarray]:
    """Control point positions [m] in the base frame, by frame name."""
    return {name: kin.frame_position(name) for name in frames}

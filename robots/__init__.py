"""Robot models: one MJCF per robot, read by MuJoCo and pinocchio alike.

Example:
    >>> import robots
    >>> jaco = robots.load("jaco2")
    >>> jaco.frame_pose(jaco.home, "end_effector")[:3, 3]  # doctest: +SKIP
"""

from __future__ import annotations

from robots.exceptions import (
    InvalidConfiguration,
    RobotError,
    StaleKinematics,
    UnknownFrame,
    UnknownRobot,
)
from robots.kinematics import Kinematics
from robots.robot import Robot, available_robots, load

__all__ = [
    "InvalidConfiguration",
    "Kinematics",
    "Robot",
    "RobotError",
    "StaleKinematics",
    "UnknownFrame",
    "UnknownRobot",
    "available_robots",
    "load",
]

"""Robot models: one description file (MJCF or URDF) per robot, read by MuJoCo and pinocchio alike.

Example:
    >>> import robots
    >>> robots.available_robots()  # doctest: +SKIP
    ['jaco2', 'panda', 'ur5']
    >>> panda = robots.load("panda")
    >>> panda.frame_pose(panda.home, "panda_link8")[:3, 3]  # doctest: +SKIP

Add your own with :func:`register` and a :class:`RobotSpec` (docs/robots.md).
"""

from __future__ import annotations

from robots.kernel_cache import use_kernel_cache

use_kernel_cache()  # before any kernel is compiled: robots.kinematics is the first

from robots.exceptions import (
    InvalidConfiguration,
    InvalidDescription,
    InvalidSpec,
    NotInstalled,
    RobotError,
    StaleKinematics,
    UnknownFrame,
    UnknownRobot,
)
from robots.kinematics import Kinematics
from robots.registry import (
    DEFAULT_ROBOT,
    available_robots,
    load,
    register,
    registered_robots,
    spec_of,
    unregister,
)
from robots.robot import Robot
from robots.spec import RobotSpec

__all__ = [
    "DEFAULT_ROBOT",
    "InvalidConfiguration",
    "InvalidDescription",
    "InvalidSpec",
    "Kinematics",
    "NotInstalled",
    "Robot",
    "RobotError",
    "RobotSpec",
    "StaleKinematics",
    "UnknownFrame",
    "UnknownRobot",
    "available_robots",
    "load",
    "register",
    "registered_robots",
    "spec_of",
    "unregister",
]

"""The robot-and-sensor interface of the control loop, implemented by the simulator and by ROS.

The closed loop (``compare.loop.closed_loop``) only talks to a :class:`RobotIO`: it reads the latest
joint state and depth frame, sends a joint velocity, and waits for the next control period.
The MuJoCo simulation steps physics in :meth:`RobotIO.wait`; a hardware backend sleeps
until the next tick of its real clock.
"""

from __future__ import annotations

import abc
from typing import NamedTuple

import numpy as np

from compare.sensing.frames import DepthFrame


class JointReading(NamedTuple):
    """A joint state sample (immutable; a tuple, made at every control step).

    Attributes:
        q: Joint positions [rad], Kinova convention (the MJCF zero). Shape (n,).
        qdot: Joint velocities [rad/s]. Shape (n,).
        stamp_s: Time of the sample on the backend's clock [s].
    """

    q: np.ndarray
    qdot: np.ndarray
    stamp_s: float


class RobotIO(abc.ABC):
    """What the control loop needs from a robot and its depth sensor.

    Attributes:
        dt: Control period [s] (0.01 for the paper's 100 Hz).
        nq: Number of joints.
    """

    dt: float
    nq: int

    @abc.abstractmethod
    def now(self) -> float:
        """Current time on the backend's clock [s] (simulated time in simulation)."""

    @abc.abstractmethod
    def read_joints(self) -> JointReading | None:
        """Latest joint state, or None if none has arrived yet."""

    @abc.abstractmethod
    def read_depth(self) -> DepthFrame | None:
        """Latest depth frame, or None if none has arrived yet (the caller checks its age)."""

    def read_depth_frames(self) -> tuple[DepthFrame | None, ...]:
        """Latest frame of every depth camera, in configuration order (one camera: ``read_depth``)."""
        return (self.read_depth(),)

    @abc.abstractmethod
    def send_velocity(self, qdot: np.ndarray) -> None:
        """Command joint velocities [rad/s], shape (n,), held until the next command."""

    @abc.abstractmethod
    def wait(self) -> None:
        """Advance to the next control period (step the simulation, or sleep until the tick)."""

    def stop(self) -> None:
        """Command zero velocity."""
        self.send_velocity(np.zeros(self.nq))

    def close(self) -> None:
        """Release resources; always leaves the robot commanded to zero velocity."""
        self.stop()

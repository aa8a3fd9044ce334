"""The robot-and-sensor interface of the control loop, implemented by the simulator and by ROS.

The closed loop (``compare.loop.closed_loop``) only talks to a :class:`RobotIO`: it reads the latest
joint state and depth frame, sends a joint velocity, and waits for the next control period.
The MuJoCo simulation steps physics in :meth:`RobotIO.wait`; a hardware backend sleeps
until the next tick of its real clock.
"""

from __future__ import annotations

import abc
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class JointReading:
    """A joint state sample.

    Attributes:
        q: Joint positions [rad], Kinova convention (the MJCF zero). Shape (n,).
        qdot: Joint velocities [rad/s]. Shape (n,).
        stamp_s: Time of the sample on the backend's clock [s].
    """

    q: np.ndarray
    qdot: np.ndarray
    stamp_s: float


@dataclass(frozen=True)
class CameraModel:
    """Pinhole depth camera: intrinsics and pose in the arm base frame.

    Attributes:
        width: Image width [px].
        height: Image height [px].
        fx: Focal length along u [px].
        fy: Focal length along v [px].
        cx: Principal point u [px].
        cy: Principal point v [px].
        transform_base_to_camera: Pose of the optical frame (x right, y down, z forward) in
            the base frame, 4×4. A point p_cam maps to p_base = T[:3, :3] p_cam + T[:3, 3].
        min_range_m: Closest valid depth [m].
        max_range_m: Farthest valid depth [m].
    """

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    transform_base_to_camera: np.ndarray
    min_range_m: float = 0.5
    max_range_m: float = 4.5


@dataclass(frozen=True)
class DepthFrame:
    """One depth image along the optical axis.

    Attributes:
        depth_m: Depth [m], float32, shape (height, width); 0 or NaN = no return.
        stamp_s: Capture time on the backend's clock [s].
        camera: The camera that took it.
    """

    depth_m: np.ndarray
    stamp_s: float
    camera: CameraModel


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

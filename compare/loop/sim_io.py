"""MuJoCo implementation of :class:`~compare.loop.robot_io.RobotIO`.

``dynamic`` mode: a joint drive (:mod:`compare.loop.joint_drive`: the inverse-dynamics ``decoupled``
drive, or the MJCF's own velocity servos, ``servo``) tracks the command while MuJoCo integrates
the dynamics, with passive gravity compensation. ``kinematic`` mode: q ← q + q̇·dt exactly, then
forward kinematics (the pure-kinematics setting the solvers are analysed in).
"""

from __future__ import annotations

import copy
from collections.abc import Callable, Sequence

import mujoco
import numpy as np

from compare.loop.joint_drive import DecoupledVelocityDrive, DriveKind
from compare.loop.robot_io import JointReading, RobotIO
from compare.sensing.frames import DepthFrame


class SimRobotIO(RobotIO):
    """The arm in a MuJoCo scene, stepped one control period per :meth:`wait`.

    Args:
        model: Scene model; the arm's n joints are the first n qpos/qvel entries and its
            velocity servos the first n actuators. The ``decoupled`` drive steps a copy with
            the actuators disabled; ``model`` itself is not changed.
        nq: Number of arm joints.
        dt: Control period [s].
        q0: Start configuration [rad].
        mode: ``dynamic`` or ``kinematic``.
        scene_update: Called with (time [s], data) before each physics step to move scripted
            bodies (the person's mocap bodies).
        depth_camera: Renders a :class:`DepthFrame` from ``data``; called at most once per
            ``depth_period_s`` and only when :meth:`read_depth` asks for a newer frame.
        depth_period_s: Camera frame period [s] (1/30 s).
        depth_cameras: Several cameras instead of ``depth_camera`` (:meth:`read_depth_frames`;
            :meth:`read_depth` is the first), each at its own period ``depth_periods_s``
            (default ``depth_period_s`` for all).
        depth_periods_s: Frame period of each of ``depth_cameras`` [s].
        drive: Joint drive in ``dynamic`` mode: ``decoupled`` or ``servo``
            (:mod:`compare.loop.joint_drive`).
        drive_bandwidth_rad_s: λ of the ``decoupled`` drive [rad/s].

    Raises:
        ValueError: Unknown ``mode`` or ``drive``, or a bandwidth the model's timestep cannot
            integrate.
    """

    def __init__(
        self,
        model: mujoco.MjModel,
        nq: int,
        dt: float,
        q0: np.ndarray,
        mode: str = "dynamic",
        scene_update: Callable[[float, mujoco.MjData], None] | None = None,
        depth_camera: Callable[[mujoco.MjData], DepthFrame] | None = None,
        depth_period_s: float = 1.0 / 30.0,
        drive: DriveKind = "decoupled",
        drive_bandwidth_rad_s: float = 100.0,
        depth_cameras: Sequence[Callable[[mujoco.MjData], DepthFrame]] | None = None,
        depth_periods_s: Sequence[float] | None = None,
    ) -> None:
        if mode not in ("dynamic", "kinematic"):
            raise ValueError(f"mode must be 'dynamic' or 'kinematic', got {mode!r}")
        if drive not in ("decoupled", "servo"):
            raise ValueError(f"drive must be 'decoupled' or 'servo', got {drive!r}")
        self._drive: DecoupledVelocityDrive | None = None
        if mode == "dynamic" and drive == "decoupled":
            model = copy.copy(model)
            self._drive = DecoupledVelocityDrive(model, nq, drive_bandwidth_rad_s)
        self.model = model
        self.data = mujoco.MjData(model)
        self.nq = nq
        self.dt = dt
        self.mode = mode
        self._scene_update = scene_update
        if depth_cameras is not None and depth_camera is not None:
            raise ValueError("give depth_camera or depth_cameras, not both")
        cameras = list(depth_cameras) if depth_cameras is not None else [] if depth_camera is None else [depth_camera]
        periods = [depth_period_s] * len(cameras) if depth_periods_s is None else list(depth_periods_s)
        if len(periods) != len(cameras):
            raise ValueError(f"{len(cameras)} depth cameras but {len(periods)} periods")
        self._depth_cameras = cameras
        self._depth_periods_s = periods
        self._next_depth_t = [0.0] * len(cameras)
        self._frames: list[DepthFrame | None] = [None] * len(cameras)
        self._substeps = max(1, round(dt / model.opt.timestep))
        self._command = np.zeros(nq)
        # The arm's entries of the state and the controls, views made once (MjData's arrays are fixed).
        self._qpos, self._qvel, self._ctrl = self.data.qpos[:nq], self.data.qvel[:nq], self.data.ctrl[:nq]
        self.data.qpos[:nq] = q0
        if scene_update is not None:
            scene_update(0.0, self.data)
        mujoco.mj_forward(model, self.data)

    @property
    def substeps(self) -> int:
        """Physics steps per control period (``dt`` / the model's timestep, at least 1)."""
        return self._substeps

    def now(self) -> float:
        """Simulated time [s]."""
        return float(self.data.time)

    def read_joints(self) -> JointReading:
        """Exact joint state (no sensor model on encoders)."""
        qdot = self._command.copy() if self.mode == "kinematic" else self._qvel.copy()
        return JointReading(self._qpos.copy(), qdot, float(self.data.time))

    def read_depth(self) -> DepthFrame | None:
        """Latest frame (of the first camera), rendering a new one when the camera period has elapsed."""
        return self._latest(0) if self._depth_cameras else None

    def read_depth_frames(self) -> tuple[DepthFrame | None, ...]:
        """Latest frame of every camera, each rendered anew when its own period has elapsed."""
        return tuple(self._latest(c) for c in range(len(self._depth_cameras)))

    def _latest(self, c: int) -> DepthFrame | None:
        if self.data.time + 1e-9 >= self._next_depth_t[c]:
            self._frames[c] = self._depth_cameras[c](self.data)
            self._next_depth_t[c] += self._depth_periods_s[c]
        return self._frames[c]

    def send_velocity(self, qdot: np.ndarray) -> None:
        """Joint velocity command [rad/s] (clipped to the servos' ``ctrlrange`` by the drive)."""
        self._command = np.array(qdot, dtype=float)
        self._ctrl[:] = self._command

    def wait(self) -> None:
        """Advance one control period."""
        m, d = self.model, self.data
        if self.mode == "dynamic":
            if self._drive is not None:
                self._drive.step(m, d, self._command, self._substeps)
            else:
                mujoco.mj_step(m, d, nstep=self._substeps)
        else:
            d.qpos[: self.nq] += self._command * self.dt
            d.qvel[: self.nq] = self._command
            d.time += self.dt
        # The scene at the period's end: the arm's new state and the scripted bodies at the same
        # instant, so that what is read, rendered and judged next pairs the two at one time
        # (scripted bodies move at most ~2 cm per period: held over the period's physics steps).
        if self._scene_update is not None:
            self._scene_update(d.time, d)
        mujoco.mj_kinematics(m, d)

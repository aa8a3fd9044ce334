"""A robot model built once from its MJCF file, for MuJoCo and pinocchio alike.

The arm base frame of the paper is the root of the kinematic tree: every pose and Jacobian
returned here is expressed in it.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np
import pinocchio as pin

from robots.exceptions import InvalidConfiguration, UnknownFrame, UnknownRobot
from robots.kinematics import Kinematics

_HERE = Path(__file__).resolve().parent


@dataclass(frozen=True)
class RobotSpec:
    """Where a robot's files are and how its frames are named.

    Attributes:
        model_file: MJCF of the robot alone (the single source of truth).
        scene_file: MJCF of the robot in its scene (includes ``model_file``).
        prefix: Prefix of every body/joint name in the MJCF (e.g. ``"j2s7s300_"``).
        home: Name of the keyframe used as the default configuration.
    """

    model_file: Path
    scene_file: Path
    prefix: str
    home: str = "home"


_REGISTRY: dict[str, RobotSpec] = {
    "jaco2": RobotSpec(
        model_file=_HERE / "kinova_j2s7s300" / "j2s7s300.xml",
        scene_file=_HERE / "kinova_j2s7s300" / "scene.xml",
        prefix="j2s7s300_",
    ),
}
_ALIASES = {"j2s7s300": "jaco2", "kinova_j2s7s300": "jaco2"}


def available_robots() -> list[str]:
    """Names accepted by :func:`load`."""
    return sorted(_REGISTRY)


class Robot:
    """Kinematic model of a serial arm with revolute joints.

    Frame names are the MJCF body names, with or without the robot prefix
    (``"link_4"`` and ``"j2s7s300_link_4"`` are the same frame). Joint numbers are 1-based,
    as in the paper and the Kinova documentation.

    Attributes:
        name: Registry name.
        spec: Files and naming.
        nq: Number of joints ``n``.
        joint_names: MJCF joint names, in chain order.
        q_lower: Lower joint position limits [rad], ``-inf`` for continuous joints. Shape (n,).
        q_upper: Upper joint position limits [rad], ``+inf`` for continuous joints. Shape (n,).
        v_max: Joint velocity limits [rad/s] (the velocity actuators' ``ctrlrange``). Shape (n,).
        home: The ``home`` keyframe configuration [rad]. Shape (n,).
    """

    def __init__(self, name: str, spec: RobotSpec) -> None:
        self.name = name
        self.spec = spec
        self.mj_model = mujoco.MjModel.from_xml_path(str(spec.model_file))
        self.pin_model = pin.buildModelFromMJCF(str(spec.model_file))
        self._pin_data = self.pin_model.createData()
        self._generation = 0
        self.nq = int(self.pin_model.nq)
        if self.mj_model.nq != self.nq:
            raise ValueError(f"MuJoCo nq={self.mj_model.nq} != pinocchio nq={self.nq}")
        self.joint_names = tuple(self.mj_model.joint(i).name for i in range(self.mj_model.njnt))
        limited = self.mj_model.jnt_limited.astype(bool)
        rng = self.mj_model.jnt_range
        self.q_lower = np.where(limited, rng[:, 0], -np.inf)
        self.q_upper = np.where(limited, rng[:, 1], np.inf)
        self.v_max = self._velocity_limits()
        key = self.mj_model.keyframe(spec.home)
        self.home = np.array(key.qpos, dtype=float)
        self._frame_ids: dict[str, int] = {}
        self._frame_joint: dict[str, int] = {}
        for frame_id, frame in enumerate(self.pin_model.frames):
            if frame.type != pin.FrameType.BODY:
                continue
            self._frame_ids[frame.name] = frame_id
            # 1-based number of the joint that moves this frame (0 = fixed to the base).
            self._frame_joint[frame.name] = int(frame.parentJoint)
        self.frame_names = tuple(self._short(n) for n in self._frame_ids)
        # Lookups by either spelling in one dict access (called many times per control step).
        self._frame_by_any_name: dict[str, tuple[int, int]] = {}
        for full, fid in self._frame_ids.items():
            entry = (fid, self._frame_joint[full])
            self._frame_by_any_name[full] = entry
            self._frame_by_any_name[self._short(full)] = entry
        for axis in self.pin_model.joints[1:]:
            if axis.shortname() != "JointModelRZ":
                raise ValueError(f"only z-axis revolute joints are supported, got {axis.shortname()}")

    def _velocity_limits(self) -> np.ndarray:
        v_max = np.full(self.nq, np.inf)
        for i in range(self.mj_model.nu):
            joint_id = int(self.mj_model.actuator_trnid[i, 0])
            lo, hi = self.mj_model.actuator_ctrlrange[i]
            v_max[joint_id] = min(abs(lo), abs(hi))
        if not np.all(np.isfinite(v_max)):
            raise ValueError("every joint needs a velocity actuator whose ctrlrange gives its limit")
        return v_max

    def _short(self, name: str) -> str:
        return name.removeprefix(self.spec.prefix)

    def frame_id(self, name: str) -> int:
        """Pinocchio frame index of a body frame, by full or short name."""
        entry = self._frame_by_any_name.get(name)
        if entry is None:
            raise UnknownFrame(name, self.frame_names)
        return entry[0]

    def frame_joint(self, name: str) -> int:
        """1-based number of the joint whose motion moves the frame's origin last."""
        entry = self._frame_by_any_name.get(name)
        if entry is None:
            raise UnknownFrame(name, self.frame_names)
        return entry[1]

    def check_configuration(self, q: np.ndarray) -> np.ndarray:
        """Return ``q`` as a float array of shape (n,), or raise :class:`InvalidConfiguration`."""
        q_arr = np.array(q, dtype=float)  # a copy: the snapshot freezes it
        if q_arr.shape != (self.nq,):
            raise InvalidConfiguration(f"q must have shape ({self.nq},), got {q_arr.shape}")
        # A finite sum is the cheap test (µs matter at 100 Hz); the exact one only when it fails.
        if not math.isfinite(sum(q_arr.tolist())) and not np.isfinite(q_arr).all():
            raise InvalidConfiguration(f"q has non-finite entries: {q_arr.tolist()}")
        return q_arr

    def kinematics(self, q: np.ndarray) -> Kinematics:
        """Forward kinematics and joint Jacobians at ``q``, computed once.

        The snapshot reads frames and Jacobians lazily from the robot's pinocchio data, so
        only the most recent snapshot of a robot is valid (an older one raises
        :class:`~robots.exceptions.StaleKinematics`).
        """
        q_arr = self.check_configuration(q)
        pin.computeJointJacobians(self.pin_model, self._pin_data, q_arr)
        pin.updateFramePlacements(self.pin_model, self._pin_data)
        self._generation += 1
        return Kinematics(self, q_arr, self._pin_data, self._generation)

    def is_current(self, generation: int) -> bool:
        """Whether a snapshot of this generation still matches the robot's data."""
        return generation == self._generation

    # Convenience one-shot queries (each recomputes the kinematics).
    def frame_pose(self, q: np.ndarray, name: str) -> np.ndarray:
        """Homogeneous transform of frame ``name`` in the base frame. Shape (4, 4)."""
        return self.kinematics(q).frame_pose(name)

    def frame_position(self, q: np.ndarray, name: str) -> np.ndarray:
        """Origin of frame ``name`` in the base frame [m]. Shape (3,)."""
        return self.kinematics(q).frame_position(name)

    def frame_jacobian(self, q: np.ndarray, name: str) -> np.ndarray:
        """Geometric Jacobian ``[v; ω]`` of the frame origin in base axes. Shape (6, n)."""
        return self.kinematics(q).frame_jacobian(name)

    def position_jacobian(self, q: np.ndarray, name: str) -> np.ndarray:
        """Position Jacobian of the frame origin in the base frame. Shape (3, n)."""
        return self.kinematics(q).position_jacobian(name)

    def partial_position_jacobian(self, q: np.ndarray, name: str, joint: int | None = None) -> np.ndarray:
        """The paper's partial position Jacobian (sec. III). Shape (3, n).

        See :meth:`robots.kinematics.Kinematics.partial_position_jacobian`.
        """
        return self.kinematics(q).partial_position_jacobian(name, joint)

    def __repr__(self) -> str:
        return f"Robot(name={self.name!r}, nq={self.nq}, file={self.spec.model_file.name!r})"


@functools.cache
def _load_cached(name: str) -> Robot:
    return Robot(name, _REGISTRY[name])


def load(name: str) -> Robot:
    """Load a robot by registry name (``"jaco2"``); the model is parsed once per process.

    Raises:
        UnknownRobot: ``name`` is not registered.
    """
    key = _ALIASES.get(name, name)
    if key not in _REGISTRY:
        raise UnknownRobot(name, available_robots())
    return _load_cached(key)

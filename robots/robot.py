"""A robot model built once from its description file, for MuJoCo and pinocchio alike.

The arm base frame of the paper is the root of the kinematic tree: every pose and Jacobian
returned here is expressed in it.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Sequence
from typing import Any

import mujoco
import numpy as np
import pinocchio as pin

from robots import description as desc
from robots.exceptions import InvalidConfiguration, InvalidDescription, UnknownFrame
from robots.kinematics import Kinematics
from robots.spec import RobotSpec
from robots.workcell import workcell_model, workcell_spec


class Robot:
    """Kinematic model of a serial arm with revolute joints, from one description file.

    Frame names are the description's body (MJCF) or link (URDF) names, with or without the
    spec's prefix (``"link_4"`` and ``"j2s7s300_link_4"`` are the same frame). Joint numbers are
    1-based, as in the paper and the makers' documentation.

    Attributes:
        name: Registry name.
        spec: The robot's :class:`~robots.spec.RobotSpec`.
        nq: Number of joints ``n``.
        joint_names: The description's joint names, in chain order.
        q_lower: Lower joint position limits [rad], ``-inf`` for unlimited joints. Shape (n,).
        q_upper: Upper joint position limits [rad], ``+inf`` for unlimited joints. Shape (n,).
        v_max: Joint velocity limits [rad/s]: the spec's, else the description's (URDF
            ``<limit velocity>``); never an actuator's range. Shape (n,).
        home: Home configuration [rad] (the spec's keyframe or values). Shape (n,).
        ee_frame: End-effector frame (the spec's).
        control_points: Default obstacle control point frames (the spec's).
        base_body: The arm's root body in MuJoCo (the subtree the self-filter removes).
        frame_names: Every body frame, by its short name.

    Raises:
        InvalidDescription: the file cannot serve as the robot's single description (module
            :mod:`robots.description`), or a spec frame / home pose does not fit it.
        NotInstalled: a file the description needs is missing.
    """

    def __init__(self, name: str, spec: RobotSpec) -> None:
        self.name = name
        self.spec = spec
        path = spec.description
        self.mj_model = desc.compile_spec(self.mujoco_spec(), path)
        self.pin_model = desc.pinocchio_model(path)
        self._pin_data = self.pin_model.createData()
        self._generation = 0
        self.joint_names = desc.check_joints(path, self.mj_model, self.pin_model)
        self.nq = int(self.pin_model.nq)
        limited = self.mj_model.jnt_limited.astype(bool)
        rng = self.mj_model.jnt_range
        self.q_lower = np.where(limited, rng[:, 0], -np.inf)
        self.q_upper = np.where(limited, rng[:, 1], np.inf)
        self.v_max = desc.velocity_limits(path, self.pin_model, self.joint_names, spec.velocity_limits)
        self.home = self._home()
        root = int(self.mj_model.body_rootid[self.mj_model.jnt_bodyid[0]])
        self.base_body = self.mj_model.body(root).name
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
        self._support_cache: dict[tuple[str, ...], tuple[list[int], np.ndarray]] = {}
        self._placement_cache: dict[tuple[str, ...], tuple[np.ndarray, np.ndarray]] = {}
        self._chain: tuple[np.ndarray, np.ndarray] | None | bool = False  # not built yet
        self._origin_views: dict[str, np.ndarray] = {}  # see origin_view
        self._workcell: mujoco.MjModel | None = None  # compiled once, copied for each caller
        for full, fid in self._frame_ids.items():
            entry = (fid, self._frame_joint[full])
            self._frame_by_any_name[full] = entry
            self._frame_by_any_name[self._short(full)] = entry
        for frame in (spec.ee_frame, *spec.control_points):
            if frame not in self._frame_by_any_name:
                raise InvalidDescription(
                    f"{path}: spec frame '{frame}' is not in the description; frames: {', '.join(self.frame_names)}"
                )
        self.ee_frame = spec.ee_frame
        self.control_points = spec.control_points
        desc.check_agreement(path, self.mj_model, self.pin_model, self._check_configurations())

    def mujoco_spec(self) -> mujoco.MjSpec:
        """A fresh MuJoCo spec of the description alone (URDF options and meshes resolved)."""
        return desc.mujoco_spec(self.spec.description, self.spec.package_dirs)

    def workcell_spec(self) -> mujoco.MjSpec:
        """A fresh spec of the robot's work cell (table, depth camera, person): :mod:`robots.workcell`."""
        return workcell_spec(self)

    def workcell_model(self) -> mujoco.MjModel:
        """The compiled work cell; the arm's joints are its first ``nq`` DoFs.

        Compiled on the first call; every call returns its own copy (``mj_copyModel``, ~0.2 ms
        against ~25 ms for a compile), so a caller that edits its model changes no other's.
        """
        if self._workcell is None:
            self._workcell = workcell_model(self)
        return copy.copy(self._workcell)

    def _home(self) -> np.ndarray:
        path = self.spec.description
        home = self.spec.home
        if isinstance(home, str):
            key = mujoco.mj_name2id(self.mj_model, mujoco.mjtObj.mjOBJ_KEY, home)
            if key < 0:
                keys = [self.mj_model.key(k).name for k in range(self.mj_model.nkey)]
                raise InvalidDescription(f"{path}: no keyframe '{home}' for the home pose; keyframes: {keys}")
            q = np.array(self.mj_model.key_qpos[key], dtype=float)
        else:
            q = np.array(home, dtype=float)
            if q.shape != (self.nq,):
                raise InvalidDescription(f"{path}: home has {q.size} values for {self.nq} joints")
        outside = (q < self.q_lower - 1e-9) | (q > self.q_upper + 1e-9)
        if outside.any():
            j = int(np.flatnonzero(outside)[0])
            raise InvalidDescription(
                f"{path}: home q{j + 1} = {q[j]:.4g} rad is outside [{self.q_lower[j]:.4g}, {self.q_upper[j]:.4g}]"
            )
        return q

    def _check_configurations(self) -> list[np.ndarray]:
        """Home, zero (clipped into the limits) and three seeded random configurations."""
        lo = np.where(np.isfinite(self.q_lower), self.q_lower, -math.pi)
        hi = np.where(np.isfinite(self.q_upper), self.q_upper, math.pi)
        rng = np.random.default_rng(0)
        return [self.home, np.clip(np.zeros(self.nq), lo, hi), *(rng.uniform(lo, hi) for _ in range(3))]

    def _short(self, name: str) -> str:
        return name.removeprefix(self.spec.prefix)

    def frame_id(self, name: str) -> int:
        """Pinocchio frame index of a body frame, by full or short name."""
        entry = self._frame_by_any_name.get(name)
        if entry is None:
            raise UnknownFrame(name, self.frame_names)
        return entry[0]

    def origin_view(self, name: str) -> np.ndarray:
        """The origin of frame ``name`` in the robot's pinocchio data [m], shape (3,): a live, read-only view.

        It shows the placement of the latest computation (:meth:`Kinematics.frame_position` copies
        it); the view of each frame is made once (pinocchio's accessor costs a microsecond a call).
        """
        view = self._origin_views.get(name)
        if view is None:
            view = self._pin_data.oMf[self.frame_id(name)].translation  # a view into the data's own memory
            view.flags.writeable = False
            self._origin_views[name] = view
        return view

    def __getstate__(self) -> dict[str, Any]:
        """The robot without its views into the pinocchio data (a copy makes its own, of its own data)."""
        state = self.__dict__.copy()
        state["_origin_views"] = {}
        return state

    def mujoco_body(self, name: str) -> str:
        """Name of the MuJoCo body of a frame given by full or short name (mink's frame names)."""
        self.frame_id(name)  # raises UnknownFrame listing the frames
        prefix = self.spec.prefix
        return name if name.startswith(prefix) else prefix + name

    def frame_support(self, names: Sequence[str]) -> tuple[list[int], np.ndarray]:
        """Pinocchio frame ids of ``names`` and, per frame, which joints' velocities move it (F, n) bool.

        Cached per tuple of names (used by :meth:`Kinematics.fill_frames`).
        """
        key = tuple(names)
        cached = self._support_cache.get(key)
        if cached is None:
            model = self.pin_model
            ids = [self.frame_id(name) for name in key]
            support = np.zeros((len(key), self.nq), dtype=np.bool_)
            for f, fid in enumerate(ids):
                for jid in model.supports[model.frames[fid].parentJoint]:
                    if jid > 0:
                        idx, nv = model.joints[jid].idx_v, model.joints[jid].nv
                        support[f, idx : idx + nv] = True
            cached = self._support_cache[key] = (ids, support)
        return cached

    def revolute_chain(self) -> tuple[np.ndarray, np.ndarray] | None:
        """The joints as single-axis revolute joints for compiled forward kinematics, or None.

        Per pinocchio joint i (0 = the universe): ``(parent, axis 0/1/2, q index)`` and its
        placement in the parent (rotation row-major, translation), shape (nj, 3) int and (nj, 12);
        None when a joint is not a revolute joint about x, y or z (:meth:`Kinematics.fill_frames`
        then reads the frames from pinocchio). Built once.
        """
        if self._chain is False:
            model = self.pin_model
            axes = {"JointModelRX": 0, "JointModelRY": 1, "JointModelRZ": 2}
            chain_i = np.zeros((model.njoints, 3), dtype=np.int64)
            chain_f = np.zeros((model.njoints, 12))
            ok = model.nq == model.nv
            for i in range(1, model.njoints):
                joint = model.joints[i]
                axis = axes.get(joint.shortname())
                if axis is None:
                    ok = False
                    break
                placement = model.jointPlacements[i]
                chain_i[i] = (model.parents[i], axis, joint.idx_q)
                chain_f[i, :9] = np.asarray(placement.rotation).ravel()
                chain_f[i, 9:] = placement.translation
            self._chain = (chain_i, chain_f) if ok else None
        return self._chain  # type: ignore[return-value]

    def frame_placements(self, names: Sequence[str]) -> tuple[np.ndarray, np.ndarray]:
        """Parent joint and origin in that joint's frame [m] of each frame, (F,) int and (F, 3). Cached."""
        key = tuple(names)
        cached = self._placement_cache.get(key)
        if cached is None:
            frames = [self.pin_model.frames[self.frame_id(name)] for name in key]
            parent = np.array([f.parentJoint for f in frames], dtype=np.int64)
            offset = np.array([np.asarray(f.placement.translation) for f in frames]).reshape(len(key), 3)
            cached = self._placement_cache[key] = (parent, offset)
        return cached

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

        The snapshot reads frames and Jacobians lazily from the robot's pinocchio data
        (computed at its first query, :class:`~robots.kinematics.Kinematics`), so only the
        most recent snapshot of a robot is valid (an older one raises
        :class:`~robots.exceptions.StaleKinematics`).
        """
        q_arr = self.check_configuration(q)
        self._generation += 1
        return Kinematics(self, q_arr, self._pin_data, self._generation, pending=True)

    def renew(self, kin: Kinematics) -> Kinematics:
        """:meth:`kinematics` at ``kin.q`` (checked once, when ``kin`` was taken): nothing computed, ``kin`` stale."""
        if kin.robot is not self:
            return self.kinematics(kin.q)
        self._generation += 1
        return Kinematics(self, kin.q, self._pin_data, self._generation, pending=True)

    def _compute_pinocchio(self, q: np.ndarray) -> None:
        """Forward kinematics, joint Jacobians and frame placements at ``q`` into the robot's pinocchio data.

        Called by the current snapshot at its first query that reads the data.
        """
        pin.computeJointJacobians(self.pin_model, self._pin_data, q)
        pin.updateFramePlacements(self.pin_model, self._pin_data)

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
        return f"Robot(name={self.name!r}, nq={self.nq}, file={self.spec.description.name!r})"

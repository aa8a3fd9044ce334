"""Our tasks evaluated on mink's own kinematics: a :class:`~robots.Kinematics` view of a ``mink.Configuration``.

A mink user computes frame poses and Jacobians from ``mink.Configuration`` (MuJoCo's
``mj_kinematics`` and ``mj_jacBody`` on the model's data), not from another library. The mink
peer hands this view to the shared tasks (walls, obstacle distances, joint limits, frame
targets): the task *definitions* stay the project's (σ, its Jacobian, the paper's partial
control-point Jacobian), the numbers come from mink's MuJoCo data. MuJoCo and pinocchio read
the same MJCF: their frame positions and Jacobians agree to ~1e-14
(``tests/qp_baseline/test_mink_peer.py``).
"""

from __future__ import annotations

from collections.abc import Sequence

import mink
import mujoco
import numpy as np

from robots import Kinematics, Robot


class MinkKinematics(Kinematics):
    """Frame poses and Jacobians read from a ``mink.Configuration`` (already ``update``-d).

    The same interface as :class:`robots.Kinematics` (body frames by full or short name,
    base-frame axes, lazily cached per frame); it is a snapshot of the configuration's current
    data and must not be used after the next ``configuration.update``.

    Args:
        robot: The robot (names, joint numbering).
        configuration: mink configuration of ``robot.mj_model`` at the step's ``q``.
        bodies: Cache of MuJoCo body ids by frame name, shared between snapshots.
    """

    __slots__ = ("_bodies", "_model")

    def __init__(self, robot: Robot, configuration: mink.Configuration, bodies: dict[str, int]) -> None:
        # robots.Kinematics.__init__ takes pinocchio data: the slots are filled here instead.
        self.robot = robot
        self.q = np.array(configuration.q, dtype=float)
        self.q.flags.writeable = False
        self._model = configuration.model
        self._data = configuration.data
        self._generation = -1
        self._bodies = bodies
        self._jacobians: dict[str, np.ndarray] = {}
        self._position_jacobians: dict[str, np.ndarray] = {}
        self._positions: dict[str, np.ndarray] = {}
        self._partial_jacobians: dict[tuple[str, int | None], np.ndarray] = {}

    def _body(self, name: str) -> int:
        body = self._bodies.get(name)
        if body is None:
            full = self.robot.mujoco_body(name)  # raises UnknownFrame listing the frames
            body = int(mujoco.mj_name2id(self._model, mujoco.mjtObj.mjOBJ_BODY, full))
            self._bodies[name] = body
        return body

    def _check(self) -> None:
        """A snapshot of mink's data: no staleness bookkeeping."""

    @property
    def is_current(self) -> bool:
        """Always true (the robot's pinocchio snapshots are not involved)."""
        return True

    def frame_pose(self, name: str) -> np.ndarray:
        """Homogeneous transform base → frame. Shape (4, 4)."""
        body = self._body(name)
        pose = np.eye(4)
        pose[:3, :3] = self._data.xmat[body].reshape(3, 3)
        pose[:3, 3] = self._data.xpos[body]
        return pose

    def frame_position(self, name: str) -> np.ndarray:
        """Frame origin in the base frame [m]. Shape (3,). Read-only."""
        pos = self._positions.get(name)
        if pos is None:
            pos = self._data.xpos[self._body(name)].copy()
            pos.flags.writeable = False
            self._positions[name] = pos
        return pos

    def frame_rotation(self, name: str) -> np.ndarray:
        """Frame orientation in the base frame. Shape (3, 3)."""
        return self._data.xmat[self._body(name)].reshape(3, 3).copy()

    def frame_jacobian(self, name: str) -> np.ndarray:
        """Geometric Jacobian of the frame origin, base-frame axes, linear rows first. Shape (6, n)."""
        jac = self._jacobians.get(name)
        if jac is None:
            jac = np.empty((6, self._model.nv))
            mujoco.mj_jacBody(self._model, self._data, jac[:3], jac[3:], self._body(name))
            jac.flags.writeable = False
            self._jacobians[name] = jac
        return jac

    def position_jacobian(self, name: str) -> np.ndarray:
        """Rows ``0:3`` of :meth:`frame_jacobian` [m/rad]. Shape (3, n). Read-only."""
        jac = self._position_jacobians.get(name)
        if jac is None:
            jac = np.empty((3, self._model.nv))
            mujoco.mj_jacBody(self._model, self._data, jac, None, self._body(name))
            jac.flags.writeable = False
            self._position_jacobians[name] = jac
        return jac

    def fill_frames(self, names: Sequence[str], out: np.ndarray, compiled_origins: bool = False) -> None:
        """Origin and position Jacobian of each frame into ``out`` (F, 4, n), from mink's data.

        The numbers of :meth:`frame_position` and :meth:`position_jacobian` bit for bit (MuJoCo's
        ``xpos`` and ``mj_jacBody``), written straight into ``out`` without the per-frame caches
        (``compiled_origins`` is not used: the origins are MuJoCo's).
        """
        del compiled_origins
        xpos = self._data.xpos
        for f, name in enumerate(names):
            body = self._body(name)
            out[f, 0, :3] = xpos[body]
            mujoco.mj_jacBody(self._model, self._data, out[f, 1:4], None, body)

    def joint_origins(self) -> np.ndarray:
        """Anchors of the joints 1..n in the base frame [m]. Shape (n, 3)."""
        return np.array(self._data.xanchor[: self.nq])

    def partial_position_jacobian(self, name: str, joint: int | None = None) -> np.ndarray:
        """The paper's partial position Jacobian (columns j..n zero), see :class:`robots.Kinematics`."""
        key = (name, joint)
        jac = self._partial_jacobians.get(key)
        if jac is None:
            j = self.robot.frame_joint(name) if joint is None else int(joint)
            if not 1 <= j <= self.nq:
                raise ValueError(f"joint must be in 1..{self.nq}, got {j}")
            jac = self.position_jacobian(name).copy()
            jac[:, j - 1 :] = 0.0
            jac.flags.writeable = False
            self._partial_jacobians[key] = jac
        return jac

    def __repr__(self) -> str:
        return f"MinkKinematics(robot={self.robot.name!r}, q={np.round(self.q, 4).tolist()})"


__all__ = ["MinkKinematics"]

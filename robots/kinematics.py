"""A kinematics snapshot: frame poses and Jacobians at one configuration, computed once."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numba
import numpy as np
import pinocchio as pin

from robots.exceptions import StaleKinematics

if TYPE_CHECKING:
    from robots.robot import Robot

_LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED


@numba.njit(cache=True, nogil=True)
def _joint_poses(q: np.ndarray, chain_i: np.ndarray, chain_f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    r"""Orientation ``R[i]`` and origin ``p[i]`` of every joint frame of a chain of single-axis revolute joints.

    Joint i (1-based, parent ``chain_i[i, 0]``, axis ``chain_i[i, 1]`` ∈ {0, 1, 2}, q index
    ``chain_i[i, 2]``): :math:`{}^oR_i = {}^oR_{p}\,R^{pl}_i\,R_{axis}(q)`,
    :math:`{}^op_i = {}^op_p + {}^oR_p\,t^{pl}_i` (``chain_f[i]``: the placement rotation,
    row-major, then its translation); joint 0 is the base (identity). Pinocchio's
    ``forwardKinematics`` to round-off.
    """
    nj = chain_i.shape[0]
    R = np.empty((nj, 3, 3))
    p = np.zeros((nj, 3))
    for a in range(3):
        for b in range(3):
            R[0, a, b] = 1.0 if a == b else 0.0
    M = np.empty((3, 3))
    for i in range(1, nj):
        par, axis = chain_i[i, 0], chain_i[i, 1]
        c, s = math.cos(q[chain_i[i, 2]]), math.sin(q[chain_i[i, 2]])
        for a in range(3):
            acc = p[par, a]
            for b in range(3):
                acc += R[par, a, b] * chain_f[i, 9 + b]
                m = 0.0
                for k in range(3):
                    m += R[par, a, k] * chain_f[i, 3 * k + b]
                M[a, b] = m
            p[i, a] = acc
        u, v = (axis + 1) % 3, (axis + 2) % 3  # rotation about `axis` mixes columns u and v
        for a in range(3):
            R[i, a, axis] = M[a, axis]
            R[i, a, u] = c * M[a, u] + s * M[a, v]
            R[i, a, v] = -s * M[a, u] + c * M[a, v]
    return R, p


@numba.njit(cache=True, nogil=True)
def _origins_from_poses(
    R: np.ndarray, p: np.ndarray, frame_parent: np.ndarray, frame_t: np.ndarray, out: np.ndarray
) -> None:
    r"""Frame origins ``out[f, 0, :3]`` = :math:`{}^op_j + {}^oR_j\,t_f` (j = ``frame_parent[f]``)."""
    for f in range(frame_parent.shape[0]):
        j = frame_parent[f]
        for a in range(3):
            acc = p[j, a]
            for b in range(3):
                acc += R[j, a, b] * frame_t[f, b]
            out[f, 0, a] = acc


@numba.njit(cache=True, nogil=True)
def _frame_origins(
    q: np.ndarray,
    chain_i: np.ndarray,
    chain_f: np.ndarray,
    frame_parent: np.ndarray,
    frame_t: np.ndarray,
    out: np.ndarray,
) -> None:
    r"""Frame origins ``out[f, 0, :3]`` by forward kinematics of a chain of single-axis revolute joints.

    :func:`_joint_poses`, then a frame's origin is :math:`{}^op_j + {}^oR_j\,t_f`.
    Pinocchio's ``forwardKinematics`` to round-off, without a Python call per frame.
    """
    R, p = _joint_poses(q, chain_i, chain_f)
    _origins_from_poses(R, p, frame_parent, frame_t, out)


@numba.njit(cache=True, nogil=True)
def chain_frames(
    q: np.ndarray,
    chain_i: np.ndarray,
    chain_f: np.ndarray,
    frame_parent: np.ndarray,
    frame_t: np.ndarray,
    support: np.ndarray,
    out: np.ndarray,
) -> None:
    r"""Origin and position Jacobian of every frame of a revolute chain, from ``q`` alone, into ``out`` (F, 4, n).

    The origins are :func:`_frame_origins`'. Column ``chain_i[i, 2]`` of the position Jacobian of
    the point P = ``out[f, 0, :3]`` is the velocity of P for a unit rate of joint i,
    :math:`\omega_i \times (P - {}^op_i)` with :math:`\omega_i = {}^oR_i\,e_{axis}` the joint's
    axis in the base frame, for the joints that move the frame (``support[f, col]``), zero for the
    others: what :meth:`Kinematics.fill_frames` computes from pinocchio's joint Jacobians
    (:math:`v_O + \omega \times P` with :math:`v_O = {}^op_i \times \omega_i`), to round-off,
    with no pinocchio call (``tests/robots/test_kinematics.py``).
    """
    R, p = _joint_poses(q, chain_i, chain_f)
    _origins_from_poses(R, p, frame_parent, frame_t, out)
    n = out.shape[2]
    for f in range(out.shape[0]):
        p0, p1, p2 = out[f, 0, 0], out[f, 0, 1], out[f, 0, 2]
        for k in range(n):
            out[f, 1, k] = 0.0
            out[f, 2, k] = 0.0
            out[f, 3, k] = 0.0
        for i in range(1, chain_i.shape[0]):
            col, axis = chain_i[i, 2], chain_i[i, 1]
            if support[f, col]:
                w0, w1, w2 = R[i, 0, axis], R[i, 1, axis], R[i, 2, axis]
                d0, d1, d2 = p0 - p[i, 0], p1 - p[i, 1], p2 - p[i, 2]
                out[f, 1, col] = w1 * d2 - w2 * d1
                out[f, 2, col] = w2 * d0 - w0 * d2
                out[f, 3, col] = w0 * d1 - w1 * d0


@numba.njit(cache=True, nogil=True)
def _shift_jacobians(J_world: np.ndarray, support: np.ndarray, out: np.ndarray) -> None:
    r"""Position Jacobians of points from the joint Jacobians in the world frame, into ``out[f, 1:4]``.

    Column j of ``J_world`` (pinocchio's ``data.J`` after ``computeJointJacobians``) is the
    spatial velocity :math:`(v_O, \omega)` of joint j at the world origin; the velocity of the
    point p = ``out[f, 0, :3]`` is :math:`v_O + \omega \times p`, for the joints that move
    the frame (``support[f, j]``), zero for the others (LOCAL_WORLD_ALIGNED linear rows).
    """
    n = J_world.shape[1]
    for f in range(out.shape[0]):
        p0, p1, p2 = out[f, 0, 0], out[f, 0, 1], out[f, 0, 2]
        for j in range(n):
            if support[f, j]:
                w0, w1, w2 = J_world[3, j], J_world[4, j], J_world[5, j]
                out[f, 1, j] = J_world[0, j] + (w1 * p2 - w2 * p1)
                out[f, 2, j] = J_world[1, j] + (w2 * p0 - w0 * p2)
                out[f, 3, j] = J_world[2, j] + (w0 * p1 - w1 * p0)
            else:
                out[f, 1, j] = 0.0
                out[f, 2, j] = 0.0
                out[f, 3, j] = 0.0


class Kinematics:
    """Frame poses and Jacobians of one robot at one configuration ``q``.

    Tasks read everything they need from here, so a control step evaluates forward
    kinematics and joint Jacobians exactly once whatever the number of tasks. Frame
    Jacobians are fetched lazily and cached per frame.

    With ``pending`` (what :meth:`Robot.kinematics` gives), pinocchio's forward kinematics,
    joint Jacobians and frame placements are computed at the first query that reads them
    (the same calls on the same ``q``, so the same numbers bit for bit); a consumer that
    computes its frames from ``q`` itself (:func:`chain_frames`, TPIK) never pays for them.

    Attributes:
        robot: The robot model.
        q: Joint configuration [rad]. Shape (n,). Read-only.
    """

    __slots__ = (
        "_data",
        "_generation",
        "_jacobians",
        "_partial_jacobians",
        "_pending",
        "_position_jacobians",
        "_positions",
        "q",
        "robot",
    )

    def __init__(self, robot: Robot, q: np.ndarray, data: pin.Data, generation: int, pending: bool = False) -> None:
        self.robot = robot
        self.q = q
        self.q.flags.writeable = False
        self._data = data
        self._generation = generation
        self._pending = pending
        # Caches keyed by the frame name as given (the lookup of the frame index is skipped).
        self._jacobians: dict[str, np.ndarray] = {}
        self._position_jacobians: dict[str, np.ndarray] = {}
        self._positions: dict[str, np.ndarray] = {}
        self._partial_jacobians: dict[tuple[str, int | None], np.ndarray] = {}

    def check_current(self) -> None:
        """Raise :class:`~robots.exceptions.StaleKinematics` if a newer snapshot of the robot was taken.

        Only the check: pinocchio's data is not computed (for consumers that compute from ``q``).
        """
        if self.robot._generation != self._generation:  # Robot.is_current, inlined (hot path)
            raise StaleKinematics("this Kinematics snapshot is stale: robot.kinematics() was called again since")

    def _check(self) -> None:
        """:meth:`check_current`, then pinocchio's data at ``q`` if it is still pending (once)."""
        if self.robot._generation != self._generation:  # Robot.is_current, inlined (hot path)
            raise StaleKinematics("this Kinematics snapshot is stale: robot.kinematics() was called again since")
        if self._pending:
            self.robot._compute_pinocchio(self.q)
            self._pending = False

    @property
    def is_current(self) -> bool:
        """Whether this snapshot is still the robot's latest (not stale)."""
        return self.robot.is_current(self._generation)

    @property
    def nq(self) -> int:
        """Number of joints ``n``."""
        return self.robot.nq

    def frame_pose(self, name: str) -> np.ndarray:
        """Homogeneous transform base → frame. Shape (4, 4)."""
        self._check()
        return np.array(self._data.oMf[self.robot.frame_id(name)].homogeneous)

    def frame_position(self, name: str) -> np.ndarray:
        """Frame origin in the base frame [m]. Shape (3,). Cached per frame: read-only."""
        self._check()
        pos = self._positions.get(name)
        if pos is None:
            pos = self.robot.origin_view(name).copy()
            pos.flags.writeable = False
            self._positions[name] = pos
        return pos

    def frame_positions(self, names: Sequence[str], out: np.ndarray) -> None:
        """:meth:`frame_position` of each of ``names`` into the rows of ``out`` [m], shape (F, 3)."""
        if type(self) is not Kinematics:  # a subclass with kinematics of its own
            for f, name in enumerate(names):
                out[f] = self.frame_position(name)
            return
        self._check()
        cached, origin = self._positions, self.robot.origin_view
        for f, name in enumerate(names):
            pos = cached.get(name)
            out[f] = origin(name) if pos is None else pos

    def frame_rotation(self, name: str) -> np.ndarray:
        """Frame orientation in the base frame. Shape (3, 3)."""
        self._check()
        return np.array(self._data.oMf[self.robot.frame_id(name)].rotation)

    def frame_jacobian(self, name: str) -> np.ndarray:
        r"""Geometric Jacobian of the frame origin, base-frame axes.

        .. math:: \begin{bmatrix} \dot p \\ \omega \end{bmatrix} = J(q)\,\dot q

        Returns:
            ``J`` with linear rows first [m/rad] then angular rows [rad/rad]. Shape (6, n).
            The array is cached: do not modify it.
        """
        self._check()
        jac = self._jacobians.get(name)
        if jac is None:
            jac = pin.getFrameJacobian(self.robot.pin_model, self._data, self.robot.frame_id(name), _LWA)
            jac.flags.writeable = False
            self._jacobians[name] = jac
        return jac

    def position_jacobian(self, name: str) -> np.ndarray:
        """Rows ``0:3`` of :meth:`frame_jacobian` [m/rad]. Shape (3, n). Cached: read-only."""
        jac = self._position_jacobians.get(name)
        if jac is None:
            jac = self.frame_jacobian(name)[:3]  # checks staleness
            self._position_jacobians[name] = jac
            return jac
        self._check()
        return jac

    def fill_frames(self, names: Sequence[str], out: np.ndarray, compiled_origins: bool = False) -> None:
        """Origin and position Jacobian of each frame into ``out`` (F, 4, n), in one pass.

        ``out[f, 0, :3]`` is :meth:`frame_position` of ``names[f]`` [m], ``out[f, 1:4]`` its
        :meth:`position_jacobian` [m/rad], computed in compiled code from the joint Jacobians
        (pinocchio's to round-off, ~1e-16). The origins are pinocchio's own (bit for bit), or
        with ``compiled_origins`` (a chain of revolute joints, :meth:`Robot.revolute_chain`)
        from compiled forward kinematics (to round-off, no Python call per frame). A subclass
        with its own kinematics gets the per-frame methods.
        """
        if type(self) is not Kinematics:
            for f, name in enumerate(names):
                out[f, 0, :3] = self.frame_position(name)
                out[f, 1:4] = self.position_jacobian(name)
            return
        self._check()
        robot = self.robot
        ids, support = robot.frame_support(names)
        chain = robot.revolute_chain() if compiled_origins else None
        if chain is None:
            oMf = self._data.oMf
            for f, fid in enumerate(ids):
                out[f, 0, :3] = oMf[fid].translation
        else:
            frame_parent, frame_t = robot.frame_placements(names)
            _frame_origins(self.q, chain[0], chain[1], frame_parent, frame_t, out)
        _shift_jacobians(self._data.J, support, out)

    def joint_origins(self) -> np.ndarray:
        """Origins of the joint frames 1..n in the base frame [m]. Shape (n, 3)."""
        self._check()
        return np.array([self._data.oMi[i].translation for i in range(1, self.nq + 1)])

    def partial_position_jacobian(self, name: str, joint: int | None = None) -> np.ndarray:
        r"""The paper's partial position Jacobian of a control point (sec. III).

        .. math:: J^{1..j}_{pos} = [\,J^1_{pos}\ \cdots\ J^{j-1}_{pos}\ 0 \cdots 0\,]

        Columns ``j .. n`` (1-based) are zero: only the joints before the control point's
        joint ``j`` may move it away from an obstacle.

        Args:
            name: Control point frame (its origin is the point).
            joint: 1-based joint number ``j``; defaults to the joint moving the frame.

        Returns:
            Shape (3, n). Cached per (frame, joint): read-only.
        """
        key = (name, joint)
        jac = self._partial_jacobians.get(key)
        if jac is not None:
            self._check()
        else:
            j = self.robot.frame_joint(name) if joint is None else int(joint)
            if not 1 <= j <= self.nq:
                raise ValueError(f"joint must be in 1..{self.nq}, got {j}")
            jac = self.position_jacobian(name).copy()  # checks staleness
            jac[:, j - 1 :] = 0.0
            jac.flags.writeable = False
            self._partial_jacobians[key] = jac
        return jac

    def __repr__(self) -> str:
        return f"Kinematics(robot={self.robot.name!r}, q={np.round(self.q, 4).tolist()})"


def warm_up(nq: int) -> None:
    """Load the compiled kernels of :meth:`Kinematics.fill_frames` into this process (cache or compile).

    Called when a solver is built, so that no control step pays for it; later calls return at once.
    """
    if _shift_jacobians.signatures and _frame_origins.signatures:
        return
    out = np.zeros((1, 4, nq))
    _shift_jacobians(np.zeros((6, nq), order="F"), np.zeros((1, nq), dtype=np.bool_), out)  # pinocchio's data.J
    for writeable in (False, True):  # a snapshot's q is read-only
        q = np.zeros(nq)
        q.flags.writeable = writeable
        chain_i = np.zeros((2, 3), dtype=np.int64)
        chain_i[1, 1] = 2
        chain_f = np.zeros((2, 12))
        chain_f[1, [0, 4, 8]] = 1.0
        _frame_origins(q, chain_i, chain_f, np.ones(1, dtype=np.int64), np.zeros((1, 3)), out)

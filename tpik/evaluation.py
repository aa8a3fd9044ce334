r"""One pass that evaluates every task of a list from a kinematics snapshot, compiled.

Every method — TPIK (:mod:`tpik.solver`), the HQP cascade and the mink peer (through
:class:`qp_baseline.set_rows.SetRowBuilder` and :meth:`TaskEvaluation.evaluate`) — needs the
same numbers at each step: per set-based task σ, its Jacobian row and which activation
threshold it is past (eq. 7), per equality task σ, J, σ̃ = σ_d − σ and σ̇_d (eq. 2). Doing this
task by task in Python costs more than TPIK's whole mode search at these sizes, and it is the
same work for every method, so it is shared: :class:`TaskEvaluation` is built once per task
list and fills preallocated buffers in one numba call.

The built-in types are evaluated in compiled code from the frames they read (each frame's
origin and position Jacobian fetched once per step from the snapshot, whatever the number of
tasks on it):

* ``JointLimitTask``: σ = q_j, J = e_jᵀ;
* ``VirtualWallTask``: σ = nᵀp − d, J = nᵀJ_pos;
* ``ObstacleDistanceTask``: σ = ‖O − P‖, J = −((O − P)/‖O − P‖)ᵀ J^{1..j}_{pos} (the paper's
  partial Jacobian, sec. III); σ = +∞, J = 0 without an obstacle point; σ = 0, J = 0 when O = P;
* ``PositionTask``: σ = p, J = J_pos, σ_d = p_d, σ̇_d = ṗ_d.

Any other task (and a subclass of these, which may change what they compute) is evaluated
through its own :meth:`~tpik.tasks.task.Task.compute_state` in Python and written into the
same buffers, so the evaluator knows no more about task types than the interface; only the
known ones are faster. Thresholds and the task structure (joint, frame, normal, offset) are
read once when the evaluator is built; gains, obstacle points and targets at every step.

Buffers after :meth:`TaskEvaluation.evaluate`:

* ``set_out`` (S, 2 + n): per set task ``[σ, side, J]`` with side +1 (σ ≥ σ_{a,u}), −1
  (σ ≤ σ_{a,l}) or 0 (between, or σ non-finite);
* ``eq_out`` (M, 3 + n): per equality row ``[σ, σ̃, σ̇_d, J]``;
* ``set_in[:, SET_GAIN]`` (S,), ``eq_in[:, EQ_GAIN]`` (E,): the gains of this step [1/s].

The level of each task (``set_i[:, 3]``, :attr:`TaskEvaluation.eq_level`) is the caller's
(``levels``), for the methods that stack rows level by level.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numba
import numpy as np

from robots import Kinematics, Robot
from robots.kinematics import warm_up as warm_up_frames
from tpik.exceptions import InvalidTaskState, TargetNotSet
from tpik.tasks import JointLimitTask, ObstacleDistanceTask, PositionTask, SetTask, Task, VirtualWallTask

KIND_PYTHON, KIND_JOINT, KIND_WALL, KIND_OBSTACLE, KIND_POSITION = -1, 0, 1, 2, 3
"""Task codes of the compiled pass (``KIND_PYTHON``: evaluated by the task itself)."""

SET_SIGMA, SET_SIDE, SET_JAC = 0, 1, 2
"""Columns of ``set_out``: σ, side, then the Jacobian row."""

EQ_VALUE, EQ_ERROR, EQ_FEEDFORWARD, EQ_JAC = 0, 1, 2, 3
"""Columns of ``eq_out``: σ, σ̃, σ̇_d, then the Jacobian row."""

# Columns of ``set_in``: wall normal and offset, thresholds, obstacle point and whether it is set,
# gain, rate feed-forward, obstacle margin growth.
_N, _D, _ACT_LO, _ACT_HI, _OBS, _HAS, _GROW = 0, 3, 4, 5, 8, 11, 14
SET_SAFE_LO, SET_SAFE_HI, SET_GAIN, SET_FEEDFORWARD = 6, 7, 12, 13
"""Columns of ``set_in`` a method reads: σ_{s,l}, σ_{s,u}, the gain K [1/s] and the rate feed-forward f."""
_SET_IN = 15

EQ_GAIN = 6
"""Column of ``eq_in`` (per equality task: p_d, ṗ_d, gain) holding the gain K [1/s]."""

SET_LEVEL = 3
"""Column of ``set_i`` holding the caller's level of the task."""


@numba.njit(cache=True, nogil=True)
def _evaluate_set(
    q: np.ndarray, frames: np.ndarray, set_i: np.ndarray, set_in: np.ndarray, set_out: np.ndarray
) -> None:
    """σ, side and J of every compiled set task (``set_i`` rows: kind, frame, first zero column)."""
    n = q.shape[0]
    for s in range(set_i.shape[0]):
        kind = set_i[s, 0]
        out = set_out[s]
        if kind == KIND_JOINT:
            j = set_i[s, 1]
            out[SET_SIGMA] = q[j]
            for k in range(n):
                out[SET_JAC + k] = 0.0
            out[SET_JAC + j] = 1.0
        elif kind == KIND_WALL:
            f = frames[set_i[s, 1]]
            n0, n1, n2 = set_in[s, _N], set_in[s, _N + 1], set_in[s, _N + 2]
            out[SET_SIGMA] = (n0 * f[0, 0] + n1 * f[0, 1] + n2 * f[0, 2]) - set_in[s, _D]
            for k in range(n):
                out[SET_JAC + k] = n0 * f[1, k] + n1 * f[2, k] + n2 * f[3, k]
        elif kind == KIND_OBSTACLE:
            for k in range(n):
                out[SET_JAC + k] = 0.0
            if set_in[s, _HAS] == 0.0:
                out[SET_SIGMA] = math.inf
            else:
                f = frames[set_i[s, 1]]
                d0 = set_in[s, _OBS] - f[0, 0]
                d1 = set_in[s, _OBS + 1] - f[0, 1]
                d2 = set_in[s, _OBS + 2] - f[0, 2]
                dist = math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
                if dist < 1e-9:
                    out[SET_SIGMA] = -set_in[s, _GROW]  # O on P: contact, no usable gradient
                else:
                    out[SET_SIGMA] = dist - set_in[s, _GROW]
                    inv = -1.0 / dist
                    u0, u1, u2 = d0 * inv, d1 * inv, d2 * inv
                    for k in range(set_i[s, 2]):  # partial Jacobian: columns from joint j on are zero
                        out[SET_JAC + k] = u0 * f[1, k] + u1 * f[2, k] + u2 * f[3, k]
        sigma = out[SET_SIGMA]
        act_lo, act_hi = set_in[s, _ACT_LO], set_in[s, _ACT_HI]
        ff, gain = set_in[s, SET_FEEDFORWARD], set_in[s, SET_GAIN]
        if ff != 0.0 and gain > 0.0:  # SetTask.activation_bounds: f/K earlier
            if ff > 0.0:
                act_lo += ff / gain
            else:
                act_hi += ff / gain
        if act_hi <= sigma < math.inf:
            out[SET_SIDE] = 1.0
        elif -math.inf < sigma <= act_lo:
            out[SET_SIDE] = -1.0
        else:
            out[SET_SIDE] = 0.0


@numba.njit(cache=True, nogil=True)
def _evaluate_eq(frames: np.ndarray, eq_i: np.ndarray, eq_in: np.ndarray, eq_out: np.ndarray) -> None:
    """σ, σ̃, σ̇_d and J of every compiled equality task (``eq_i`` rows: kind, frame, first row)."""
    n = frames.shape[2]
    for e in range(eq_i.shape[0]):
        if eq_i[e, 0] != KIND_POSITION:
            continue
        f = frames[eq_i[e, 1]]
        r0 = eq_i[e, 2]
        for a in range(3):
            out = eq_out[r0 + a]
            p = f[0, a]
            out[EQ_VALUE] = p
            out[EQ_ERROR] = eq_in[e, a] - p
            out[EQ_FEEDFORWARD] = eq_in[e, 3 + a]
            for k in range(n):
                out[EQ_JAC + k] = f[1 + a, k]


@numba.njit(cache=True, nogil=True)
def evaluate_compiled(
    q: np.ndarray,
    frames: np.ndarray,
    set_i: np.ndarray,
    set_in: np.ndarray,
    set_out: np.ndarray,
    eq_i: np.ndarray,
    eq_in: np.ndarray,
    eq_out: np.ndarray,
) -> None:
    """The compiled pass: every set task's σ, side, J and every position task's rows (module docstring).

    ``frames`` (F, 4, n): per frame its origin (row 0, first three entries) and its position
    Jacobian (rows 1–3). Python-evaluated set tasks (kind −1) have σ and J filled already; only
    their side is computed here.
    """
    _evaluate_set(q, frames, set_i, set_in, set_out)
    _evaluate_eq(frames, eq_i, eq_in, eq_out)


class TaskEvaluation:
    """Buffers and the one evaluation pass of a fixed list of tasks (module docstring).

    Args:
        tasks: The tasks, in the order the method reads them (set-based and equality tasks are
            kept in that order in two lists: :attr:`set_tasks`, :attr:`eq_tasks`).
        robot: The robot (``nq``, the joint of each control point).
        levels: The caller's level of each task (default all 0), stored in ``set_i[:, 3]`` and
            :attr:`eq_level` (per equality row).
        jacobians: ``"all"``: every set task's Jacobian row is evaluated; ``"candidates"``: a
            Python-evaluated set task's only when it is past an activation threshold (TPIK reads
            no other). Compiled tasks always get theirs (it costs nothing there).
        compiled_origins: Frame origins from the snapshot's compiled forward kinematics
            (:meth:`robots.Kinematics.fill_frames`; equal to pinocchio's to ~1e-16 m, no Python
            call per frame) instead of pinocchio's placements bit for bit. TPIK uses it; the
            QP methods do not, because their answers are not robust to such round-off (HQP's
            velocity in the null space of its rows moved by up to 3e-4 rad/s on the random
            states of ``tests/regression`` for a 1e-16 m change of a frame origin).

    Attributes:
        set_tasks, eq_tasks: The tasks by kind, in the given order.
        eq_ptr: Equality task ``i`` owns rows ``eq_ptr[i]:eq_ptr[i + 1]`` of ``eq_out``.
        eq_level: Level of each equality row. Shape (M,).
        fused: Whether the compiled pass alone completes the evaluation after :meth:`gather`
            (no Python-evaluated set task waits for its Jacobian), so a method may run
            :func:`evaluate_compiled` inside its own compiled step.
        compiled_only: Whether every task is of a compiled kind: the frames
            (:attr:`frame_names`) and :meth:`gather_inputs` are all the compiled pass reads, so
            a method may compute the frames itself (:func:`robots.kinematics.chain_frames`).
    """

    def __init__(
        self,
        tasks: Sequence[Task],
        robot: Robot,
        levels: Sequence[int] | None = None,
        jacobians: str = "all",
        compiled_origins: bool = False,
    ) -> None:
        if jacobians not in ("all", "candidates"):
            raise ValueError(f"jacobians must be 'all' or 'candidates', got {jacobians!r}")
        self.nq = n = int(robot.nq)
        self.all_jacobians = jacobians == "all"
        self.compiled_origins = compiled_origins
        self.set_tasks: tuple[SetTask, ...] = tuple(t for t in tasks if isinstance(t, SetTask))
        self.eq_tasks: tuple[Task, ...] = tuple(t for t in tasks if not isinstance(t, SetTask))
        self._frames: dict[str, int] = {}
        level_of = dict(zip([id(t) for t in tasks], levels if levels is not None else [0] * len(tasks), strict=True))
        self._layout_set_tasks(robot, level_of)
        self._layout_eq_tasks(level_of)
        self.frame_names = tuple(self._frames)
        self.frames = np.zeros((len(self._frames), 4, n))
        self._set_direct = {s: type(self.set_tasks[s]).compute_state is SetTask.compute_state for s in self._python_set}
        self.fused = not (self._python_set and not self.all_jacobians)
        self.compiled_only = not (self._python_set or self._python_eq)
        # What gather_inputs last wrote: the tasks' own arrays (set anew, as copies, by their
        # setters) and the gains; an unchanged one is not written again.
        self._seen_obstacles: list[np.ndarray | None] = [None] * len(self._obstacles)
        self._seen_targets: list[tuple[np.ndarray | None, np.ndarray | None]] = [(None, None)] * len(self._positions)
        self._seen_set_gains: list[float] = []
        self._seen_eq_gains: list[float] = []

    def _frame(self, name: str) -> int:
        """Index of a frame in :attr:`frames` (added at first use)."""
        return self._frames.setdefault(name, len(self._frames))

    def _layout_set_tasks(self, robot: Robot, level_of: dict[int, int]) -> None:
        """Codes, thresholds and buffers of the set tasks (read once)."""
        n, S = self.nq, len(self.set_tasks)
        self.set_i = np.full((S, 4), KIND_PYTHON, dtype=np.int64)
        self.set_in = np.zeros((S, _SET_IN))
        self.set_out = np.zeros((S, SET_JAC + n))
        self._python_set: list[int] = []
        self._obstacles: list[tuple[int, ObstacleDistanceTask]] = []
        for s, task in enumerate(self.set_tasks):
            th = task.thresholds
            self.set_in[s, _ACT_LO : SET_SAFE_HI + 1] = (
                th.activation_lower,
                th.activation_upper,
                th.safety_lower,
                th.safety_upper,
            )
            exact = type(task)  # a subclass may compute something else: it evaluates itself
            self.set_i[s, SET_LEVEL] = level_of[id(task)]
            if exact is JointLimitTask and isinstance(task, JointLimitTask):
                self.set_i[s, :3] = (KIND_JOINT, task.joint - 1, 0)
            elif exact is VirtualWallTask and isinstance(task, VirtualWallTask):
                self.set_i[s, :3] = (KIND_WALL, self._frame(task.frame), 0)
                self.set_in[s, _N : _N + 3] = task.normal
                self.set_in[s, _D] = task.offset
            elif exact is ObstacleDistanceTask and isinstance(task, ObstacleDistanceTask):
                j = robot.frame_joint(task.frame) if task.joint is None else int(task.joint)
                if not 1 <= j <= n:
                    raise ValueError(f"joint must be in 1..{n}, got {j}")
                self.set_i[s, :3] = (KIND_OBSTACLE, self._frame(task.frame), j - 1)
                self._obstacles.append((s, task))
            else:
                self._python_set.append(s)

    def _layout_eq_tasks(self, level_of: dict[int, int]) -> None:
        """Row ranges, codes and buffers of the equality tasks (read once)."""
        self.eq_ptr = np.zeros(len(self.eq_tasks) + 1, dtype=np.int64)
        for e, eq_task in enumerate(self.eq_tasks):
            self.eq_ptr[e + 1] = self.eq_ptr[e] + eq_task.dim
        E, M = len(self.eq_tasks), int(self.eq_ptr[-1])
        self.eq_i = np.full((E, 3), KIND_PYTHON, dtype=np.int64)
        self.eq_i[:, 2] = self.eq_ptr[:-1]  # every task's first row (Python-evaluated ones too)
        self.eq_in = np.zeros((E, 7))
        self.eq_level = np.zeros(M, dtype=np.int64)
        self.eq_out = np.zeros((M, EQ_JAC + self.nq))
        self._python_eq: list[int] = []
        self._positions: list[tuple[int, PositionTask]] = []
        for e, eq_task in enumerate(self.eq_tasks):
            self.eq_level[self.eq_ptr[e] : self.eq_ptr[e + 1]] = level_of[id(eq_task)]
            if type(eq_task) is PositionTask and isinstance(eq_task, PositionTask):
                self.eq_i[e] = (KIND_POSITION, self._frame(eq_task.frame), self.eq_ptr[e])
                self._positions.append((e, eq_task))
            else:
                self._python_eq.append(e)

    @property
    def set_gain(self) -> np.ndarray:
        """Gain of each set task at the last evaluation [1/s]. Shape (S,)."""
        return self.set_in[:, SET_GAIN]

    def evaluate(self, kin: Kinematics) -> None:
        """Fill every buffer at ``kin``: :meth:`gather`, then the compiled pass (module docstring).

        Raises:
            InvalidTaskState: A Python-evaluated task returned a wrong shape or a non-finite
                Jacobian (naming it).
            tpik.exceptions.TargetNotSet: A position task has no target.
        """
        self.gather(kin)
        evaluate_compiled(kin.q, self.frames, self.set_i, self.set_in, self.set_out, self.eq_i, self.eq_in, self.eq_out)
        if not self.fused:
            self._python_candidate_jacobians(kin)

    def gather(self, kin: Kinematics) -> None:
        """The Python part of :meth:`evaluate`: frames, :meth:`gather_inputs`, Python-evaluated tasks."""
        kin.fill_frames(self.frame_names, self.frames, self.compiled_origins)
        self.gather_inputs()
        if self._python_set:
            self._evaluate_python_set(kin)
        if self._python_eq:
            self._evaluate_python_eq(kin)

    def gather_inputs(self) -> None:
        """Obstacle points, targets and gains of this step into ``set_in`` / ``eq_in``.

        Everything the compiled pass reads besides the frames (a method computing its frames
        from ``q``, :attr:`compiled_only`, needs no more). A value that is the same object as
        the one written last (a task's point or target is replaced, as a copy, by its setter)
        or the same gains is not written again.

        Raises:
            tpik.exceptions.TargetNotSet: A position task has no target.
        """
        set_in = self.set_in
        seen = self._seen_obstacles
        # The tasks' own arrays, read without the copy their public properties make (same package).
        for k, (s, ob) in enumerate(self._obstacles):
            point = ob._obstacle
            if point is seen[k] and point is not None:
                continue
            if point is None:
                set_in[s, _HAS] = 0.0
                set_in[s, SET_FEEDFORWARD] = set_in[s, _GROW] = 0.0
            else:
                set_in[s, _OBS : _OBS + 3] = point
                set_in[s, _HAS] = 1.0
                set_in[s, SET_FEEDFORWARD] = ob._feedforward  # set with the point (same setter)
                set_in[s, _GROW] = ob._growth
            seen[k] = point
        if self._positions:
            self._gather_targets()
        if self.set_tasks:
            gains = [t.gain for t in self.set_tasks]
            if gains != self._seen_set_gains:
                set_in[:, SET_GAIN] = gains
                self._seen_set_gains = gains
        if self.eq_tasks:
            gains = [t.gain for t in self.eq_tasks]
            if gains != self._seen_eq_gains:
                self.eq_in[:, EQ_GAIN] = gains
                self._seen_eq_gains = gains

    def _gather_targets(self) -> None:
        """Target p_d and its rate ṗ_d of every compiled position task into ``eq_in`` (when replaced)."""
        eq_in, seen = self.eq_in, self._seen_targets
        for k, (e, pt) in enumerate(self._positions):
            target, velocity = pt._target, pt._velocity
            if target is None:
                raise TargetNotSet(pt.name)
            last_target, last_velocity = seen[k]
            if target is not last_target:
                eq_in[e, :3] = target
            if velocity is not last_velocity:
                eq_in[e, 3:6] = velocity
            seen[k] = (target, velocity)

    def _evaluate_python_set(self, kin: Kinematics) -> None:
        n = self.nq
        out = self.set_out
        for s in self._python_set:
            task = self.set_tasks[s]
            self.set_in[s, SET_FEEDFORWARD] = task.rate_feedforward
            if self._set_direct[s] and not self.all_jacobians:
                out[s, SET_SIGMA] = float(task.compute_value(kin))
                out[s, SET_JAC:] = 0.0  # filled for candidates after the compiled pass
                continue
            state = task.compute_state(kin)
            state.validate(task.name, n)
            out[s, SET_SIGMA] = float(state.value[0])
            out[s, SET_JAC:] = state.jacobian[0]

    def _python_candidate_jacobians(self, kin: Kinematics) -> None:
        n = self.nq
        out = self.set_out
        for s in self._python_set:
            if not self._set_direct[s] or out[s, SET_SIDE] == 0.0:
                continue
            task = self.set_tasks[s]
            jac = task.compute_jacobian(kin)
            if jac.shape != (1, n):
                raise InvalidTaskState(f"task '{task.name}': jacobian has shape {jac.shape}, expected (1, {n})")
            out[s, SET_JAC:] = jac[0]

    def _evaluate_python_eq(self, kin: Kinematics) -> None:
        n = self.nq
        out, ptr = self.eq_out, self.eq_ptr
        for e in self._python_eq:
            task = self.eq_tasks[e]
            state = task.compute_state(kin)
            m = state.value.shape[0]
            if (
                m != ptr[e + 1] - ptr[e]
                or state.jacobian.shape != (m, n)
                or state.error.shape != (m,)
                or state.feedforward.shape != (m,)
                or state.desired.shape != (m,)
            ):
                state.validate(task.name, n)  # raises InvalidTaskState naming the array
                raise InvalidTaskState(f"task '{task.name}': value has {m} entries, expected {ptr[e + 1] - ptr[e]}")
            rows = out[ptr[e] : ptr[e + 1]]
            rows[:, EQ_VALUE] = state.value
            rows[:, EQ_ERROR] = state.error
            rows[:, EQ_FEEDFORWARD] = state.feedforward
            rows[:, EQ_JAC:] = state.jacobian

    def first_non_finite(self) -> str | None:
        """Name of the first task (set tasks first) whose Jacobian in the buffers is not finite."""
        for s, task in enumerate(self.set_tasks):
            if not np.isfinite(self.set_out[s, SET_JAC:]).all():
                return task.name
        for e, eq_task in enumerate(self.eq_tasks):
            if not np.isfinite(self.eq_out[self.eq_ptr[e] : self.eq_ptr[e + 1], EQ_JAC:]).all():
                return eq_task.name
        return None


def warm_up(nq: int) -> None:
    """Load the compiled pass (and the frame kernels) into this process: no control step pays for it."""
    warm_up_frames(nq)
    if evaluate_compiled.signatures:
        return
    for writeable in (False, True):  # a snapshot's q is read-only; mink's configuration.q is not
        q = np.zeros(nq)
        q.flags.writeable = writeable
        evaluate_compiled(
            q,
            np.zeros((1, 4, nq)),
            np.zeros((0, 4), dtype=np.int64),
            np.zeros((0, _SET_IN)),
            np.zeros((0, SET_JAC + nq)),
            np.zeros((0, 3), dtype=np.int64),
            np.zeros((0, 7)),
            np.zeros((0, EQ_JAC + nq)),
        )


__all__ = [
    "EQ_ERROR",
    "EQ_FEEDFORWARD",
    "EQ_GAIN",
    "EQ_JAC",
    "EQ_VALUE",
    "SET_FEEDFORWARD",
    "SET_GAIN",
    "SET_JAC",
    "SET_LEVEL",
    "SET_SAFE_HI",
    "SET_SAFE_LO",
    "SET_SIDE",
    "SET_SIGMA",
    "TaskEvaluation",
    "evaluate_compiled",
    "warm_up",
]

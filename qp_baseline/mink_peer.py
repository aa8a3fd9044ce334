r"""The mink peers: the project's hierarchy built in mink (weighted, not strict, priorities).

mink solves one QP per step over the configuration displacement :math:`\Delta q = \dot q\,dt`:

.. math::
    \min_{\Delta q}\ \sum_i c_i^2 \|J_i \Delta q + \alpha_i e_i\|^2 + \mu \|\Delta q\|^2
    \quad \text{s.t.}\quad G \Delta q \le h

and returns :math:`v = \Delta q / dt` [rad/s] (what :func:`mink.solve_ik` does; ``dt`` scales
the constraints, e.g. ``VelocityLimit`` gives :math:`|\Delta q| \le v_{max} dt`).

mink's own parts where mink has them (kinematics from ``mink.Configuration``, frame targets
through ``FrameTask``, ``ConfigurationLimit`` and ``VelocityLimit``), and two custom parts for
the project's set-based tasks: a :class:`mink.Limit` of rows that the zero step always satisfies
(as ``ConfigurationLimit`` and ``CollisionAvoidanceLimit`` are written) and, in ``mink``, a
weighted :class:`mink.Task` that pulls a task past its safety threshold back. That return task
is the project's, not a mink idiom: mink's own limits bound the step and none of them pulls a
quantity back into a safe set.

* **Kinematics**: every task is evaluated on :class:`~qp_baseline.mink_kinematics.MinkKinematics`,
  mink's own ``Configuration`` (MuJoCo data), not on our pinocchio snapshot. The obstacle points
  are those of the shared sensing, set on the same task objects as for every method. Every
  task is evaluated in one pass of the shared evaluation (:class:`tpik.evaluation.TaskEvaluation`,
  as TPIK and HQP evaluate theirs): σ, J and the limit rows of the set-based tasks, σ̃ and σ̇_d
  of the equality tasks.
* **Frame tasks**: position / orientation / pose tasks become a :class:`mink.FrameTask` on the
  same MJCF body (position cost only for a position task, orientation cost only for an
  orientation task). The one control reference :math:`r = \dot\sigma_d + K\tilde\sigma` of
  :mod:`tpik.reference` becomes the frame target :math:`p_t = p + r_p\,dt/\alpha`,
  :math:`R_t = \mathrm{Exp}(r_\omega dt/\alpha) R` with the mink gain :math:`\alpha = \min(1, K dt)`,
  so that :math:`\alpha (p_t - p) = r_p\,dt`: with no feedforward and :math:`K dt \le 1` the
  target is exactly :math:`p_d`. Other equality tasks (e.g. manipulability) become a small
  :class:`mink.Task` with error :math:`e = -r\,dt` and the task's Jacobian.
* **Set-based tasks, formulation ``soft_return`` (method ``mink``)**: one :class:`SetTaskLimit`
  (a :class:`mink.Limit`) with the rows of :mod:`qp_baseline.set_rows` relaxed so that
  :math:`\Delta q = 0` satisfies them (``hold_at_zero``): inside its safety set a task may
  approach its threshold no faster than its reference :math:`K(\sigma_s - \sigma)`; past it, no
  further. Coming back into the safe set is a soft task (:class:`SetTaskReturn`): for each task
  past its safety threshold, :math:`J\Delta q \to K(\sigma_s - \sigma)\,dt`, weighted above the
  operational tasks (the hierarchy's order, one factor ρ per level). With the joint limits
  (``ConfigurationLimit``, ``VelocityLimit``) every limit holds at :math:`\Delta q = 0` while q is
  inside the model's joint ranges, so the QP always has a solution there.
* **Formulation ``hard`` (method ``mink-hard``, the project's earlier adapter)**: the set-task rows are
  HQP's hard return-rate rows :math:`\dot\sigma_l\,dt \le J\Delta q \le \dot\sigma_u\,dt` with
  no slack, and no return task: a task past its threshold *demands* its return rate, and when
  the rows cannot all hold (a person closer than the arm can retreat from within its velocity
  limits) mink finds no solution and the step is FAILED.
* **Method ``mink-posture``**: ``mink`` (formulation ``soft_return``) with the regularisation
  mink's examples give a redundant arm (:data:`POSTURE_PRESET`): a :class:`mink.PostureTask`
  toward the start posture (the ``q`` of the hierarchy's first solve), ``lm_damping`` on every
  ``FrameTask`` and solver damping µ. Without them the Hessian is singular in the EE task's null
  space (eigenvalues at mink's default µ = 1e-12, the answer a minimum-norm one by accident);
  with them every eigenvalue is at least µ + posture_cost². In the examples the frame and the
  posture task both have gain 1 (each asks its whole error in one step); here the frame task
  asks α = K dt of it (the control reference's rate), and the posture task takes the same α, so
  that the two keep the examples' ratio (with gain 1 the posture would be 1/α ≈ 50 times
  stronger against the EE and hold the arm near its start).
* Joint limits: by default mink's own :class:`mink.ConfigurationLimit` (gain
  ``configuration_limit_gain``) and :class:`mink.VelocityLimit` (``robot.v_max``); the same
  limits as :mod:`tpik.limits` objects are :attr:`MinkSolver.limits`. Other limits (e.g. an
  acceleration limit) are passed as ``limits`` and become one mink limit (:class:`JointLimits`);
  no method name passes any.

Priorities are weights (mink's nature): the levels, highest first, get the costs
:math:`c_k = \rho^{-k}` (:math:`\rho` = ``level_cost_ratio``, default 10, i.e. a factor 100 per
level on the squared residual), counted so that the first level with an equality task has cost 1.
In ``mink`` the return tasks of the safety levels above it so get :math:`\rho, \rho^2, \dots`.

A step calls :func:`mink.build_ik` then :func:`qpsolvers.solve_problem` and divides by ``dt``,
which is all :func:`mink.solve_ik` does besides a limit check that only logs; the build and solve
times can so be reported apart. The answer is checked as mink's own problem states it:
:math:`G\Delta q \le h` to the backend's tolerance (:data:`qp_baseline.backends.BACKENDS`, in Δq
units). A backend's no-solution or a failed check gives a FAILED step with zero velocity; an
error of a task (:class:`tpik.TpikError`) propagates, as from every solver.
"""

from __future__ import annotations

import math
import time
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, fields
from typing import Any

import mink
import mujoco
import numpy as np
import qpsolvers

from qp_baseline.backend_call import available_qp_solvers, backend_iterations, backend_kwargs, probe_settings
from qp_baseline.backends import BACKENDS
from qp_baseline.exceptions import InvalidSettings, UnknownSolver
from qp_baseline.mink_kinematics import MinkKinematics
from qp_baseline.set_rows import SetRowBuilder, SetRows
from qp_baseline.time_limits import TimeLimited
from robots import Kinematics, Robot
from tpik.evaluation import EQ_ERROR, EQ_FEEDFORWARD, EQ_JAC, SET_JAC, TaskEvaluation
from tpik.hierarchy import Hierarchy
from tpik.limits import Limit, PositionLimit, VelocityLimit, stack_inequalities
from tpik.reference import ControlReference
from tpik.step_result import SolveStatus, StepResult, failed
from tpik.tasks import OrientationTask, PoseTask, PositionTask, SetTask, Task

FORMULATIONS: tuple[str, ...] = ("soft_return", "hard")
"""The set-task formulations (module docstring)."""

POSTURE_PRESET: dict[str, Any] = {"posture_cost": 1e-2, "lm_damping": 1.0, "damping": 1e-3}
"""What ``mink-posture`` adds to ``mink``: the regularisation of mink's examples for arms.

From mink's ``franka_emika_panda.py`` example (a 7-joint arm, as the Jaco²): ``PostureTask``
cost 1e-2, ``FrameTask`` ``lm_damping`` 1.0, ``solve_ik`` damping 1e-3. The ``arm_iiwa.py``
example (KUKA iiwa 14) uses the same three values, ``arm_ur5e.py`` the same ``lm_damping`` and
damping (no posture task).
"""

MINK_METHODS: dict[str, tuple[str, dict[str, Any]]] = {
    "mink": ("soft_return", {}),
    "mink-hard": ("hard", {}),
    "mink-posture": ("soft_return", POSTURE_PRESET),
}
"""Method name → (formulation, settings preset); the config's settings override the preset key by key."""


@dataclass(frozen=True)
class MinkSettings:
    r"""Settings of the mink peer (the ``[methods.settings.mink]`` table of a config).

    Attributes:
        solver: QP backend mink hands its problem to (any name of
            :func:`qp_baseline.hqp.available_qp_solvers`).
        damping: mink's Levenberg–Marquardt damping µ on :math:`\|\Delta q\|^2` (mink's default;
            ``mink-posture``: 1e-3, :data:`POSTURE_PRESET`).
        level_cost_ratio: ρ ≥ 1: the k-th level below the first equality level has cost ρ^-k,
            the k-th above it (set-task return tasks) ρ^k: the return weight of ``mink`` and
            ``mink-posture`` (10: costs 1000 / 100 / 10 over three safety levels).
        posture_cost: Cost of a :class:`mink.PostureTask` toward the start posture (the ``q`` of
            the first solve of a hierarchy), per joint [1/rad]; 0 = no posture task
            (``mink-posture``: 1e-2).
        lm_damping: ``lm_damping`` of every :class:`mink.FrameTask`: µ = lm_damping · (its
            weighted squared error) added to the Hessian's diagonal (``mink-posture``: 1.0).
        configuration_limit_gain: Gain in (0, 1] of :class:`mink.ConfigurationLimit`.
        tolerance: Accepted violation of the returned step's constraints, in Δq units [rad or
            task unit]; None = the backend's tolerance (:data:`qp_baseline.backends.BACKENDS`).
        gain_cap: Cap every task gain at 1/dt in the control reference (:mod:`tpik.reference`;
            the same default as TPIK and HQP).
        qp_settings: Keyword arguments forwarded to the QP backend.
    """

    solver: str = "daqp"
    damping: float = 1e-12
    level_cost_ratio: float = 10.0
    posture_cost: float = 0.0
    lm_damping: float = 0.0
    configuration_limit_gain: float = 0.95
    tolerance: float | None = None
    gain_cap: bool = True
    qp_settings: Mapping[str, Any] | None = None

    @classmethod
    def from_dict(cls, data: Mapping[str, Any] | None) -> MinkSettings:
        """Validate a plain dict; unknown keys and bad values raise :class:`InvalidSettings`."""
        data = dict(data or {})
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise InvalidSettings(
                "mink", f"unknown setting '{unknown[0]}'; known: {', '.join(sorted(known))}", unknown[0]
            )
        settings = cls(**data)
        settings.check()
        return settings

    def check(self) -> None:
        """Raise :class:`InvalidSettings` naming the first bad value."""
        if self.solver not in available_qp_solvers():
            raise UnknownSolver(self.solver, available_qp_solvers())
        checks = [
            ("damping", self.damping, lambda v: v >= 0.0, ">= 0"),
            ("level_cost_ratio", self.level_cost_ratio, lambda v: v >= 1.0, ">= 1"),
            ("posture_cost", self.posture_cost, lambda v: v >= 0.0, ">= 0"),
            ("lm_damping", self.lm_damping, lambda v: v >= 0.0, ">= 0"),
            ("configuration_limit_gain", self.configuration_limit_gain, lambda v: 0.0 < v <= 1.0, "in (0, 1]"),
        ]
        if self.tolerance is not None:
            checks.append(("tolerance", self.tolerance, lambda v: v > 0.0, "> 0"))
        for key, value, ok, expected in checks:
            number = isinstance(value, int | float) and not isinstance(value, bool)
            if not number or not math.isfinite(value) or not ok(value):
                raise InvalidSettings("mink", f"setting '{key}' must be a finite number {expected}, got {value!r}", key)
        if not isinstance(self.gain_cap, bool):
            raise InvalidSettings(
                "mink", f"setting 'gain_cap' must be true or false, got {self.gain_cap!r}", "gain_cap"
            )
        if self.qp_settings is not None and not isinstance(self.qp_settings, Mapping):
            raise InvalidSettings("mink", f"'qp_settings' must be a table, got {self.qp_settings!r}", "qp_settings")


class SetTaskLimit(mink.Limit):
    r"""Set-based tasks as a mink limit: rows :math:`G \Delta q \le h\,dt` (h per second).

    The rows are loaded each step by :meth:`set_rows` (from :mod:`qp_baseline.set_rows`).
    """

    def __init__(self, nv: int) -> None:
        self.nv = nv
        self._G = np.zeros((0, nv))
        self._h = np.zeros(0)

    def set_rows(self, G: np.ndarray, h: np.ndarray) -> None:
        """Load ``G q̇ ≤ h`` [h in task units per second]."""
        self._G, self._h = G, h

    def compute_qp_inequalities(self, configuration: mink.Configuration, dt: float) -> mink.Constraint:
        r"""Rows :math:`G \Delta q \le h\,dt` (``configuration`` is unused: rows come from our tasks)."""
        del configuration
        if self._h.size == 0:
            return mink.Constraint()
        return mink.Constraint(G=self._G, h=self._h * dt)


class JointLimits(mink.Limit):
    r"""Our joint limits (:mod:`tpik.limits`) as one mink limit: every limit's rows, :math:`G\Delta q \le h\,dt`.

    The default limits stand for mink's own ``ConfigurationLimit`` (position box, gain γ) and
    ``VelocityLimit`` and give their rows in their order: :math:`\Delta q \le \gamma(q_{max} - q)`,
    :math:`-\Delta q \le \gamma(q - q_{min})` on the limited joints, then :math:`|\Delta q| \le v_{max} dt`.
    """

    def __init__(self, limits: Sequence[Limit]) -> None:
        self.limits = tuple(limits)

    def compute_qp_inequalities(self, configuration: mink.Configuration, dt: float) -> mink.Constraint:
        r"""Rows of every limit at ``configuration.q`` (hinge joints: q is the joint vector), in Δq units."""
        G, h = stack_inequalities(self.limits, configuration.q, dt)
        if h.size == 0:
            return mink.Constraint()
        return mink.Constraint(G=G, h=h * dt)


class _StateTask(mink.Task):
    """A task of stored rows as a mink task: error ``e`` (Δq units) and Jacobian set each step."""

    def __init__(self, cost: np.ndarray) -> None:
        super().__init__(cost=np.asarray(cost, dtype=float), gain=1.0)
        self.error = np.zeros(len(cost))
        self.jacobian = np.zeros((len(cost), 0))

    def compute_error(self, configuration: mink.Configuration) -> np.ndarray:
        """The stored error."""
        return self.error

    def compute_jacobian(self, configuration: mink.Configuration) -> np.ndarray:
        """The stored Jacobian."""
        return self.jacobian


class SetTaskReturn(_StateTask):
    r"""Soft return of the set-based tasks past their safety thresholds (formulation ``soft_return``).

    One row per set task: for a task past a safety threshold, :math:`J\Delta q \approx
    K(\sigma_s - \sigma)\,dt` (error :math:`e = -K(\sigma_s - \sigma)\,dt`, its Jacobian row);
    zero elsewhere (no contribution). Costs per row from the task's level.
    """


@dataclass
class _Adapter:
    """One of our equality tasks and the mink task that stands for it."""

    task: Task
    mink_task: mink.Task
    kind: str  # "position" | "orientation" | "pose" | "state"
    body_id: int = -1  # MuJoCo body of a frame task
    rows: slice = field(default_factory=lambda: slice(0, 0))  # the task's rows of the evaluation's ``eq_out``


def _frame_target(rotation: np.ndarray, position: np.ndarray) -> mink.SE3:
    """``mink.SE3.from_matrix`` of the pose (rotation, position) without building the 4×4 matrix (same numbers)."""
    wxyz_xyz = np.empty(7)
    mujoco.mju_mat2Quat(wxyz_xyz[:4], rotation.ravel())  # what mink's SO3.from_matrix does
    wxyz_xyz[4:] = position
    return mink.SE3(wxyz_xyz=wxyz_xyz)


def _so3_exp(omega: np.ndarray) -> np.ndarray:
    """Rodrigues' formula: rotation matrix of the rotation vector ``omega`` [rad]."""
    angle = float(np.linalg.norm(omega))
    if angle < 1e-12:
        return np.eye(3)
    k = omega / angle
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + math.sin(angle) * K + (1.0 - math.cos(angle)) * (K @ K)


class MinkSolver(TimeLimited):
    """The mink peer behind the shared ``solve(hierarchy, kin, dt)`` interface.

    Args:
        robot: The robot; mink gets ``robot.mj_model`` (same MJCF as pinocchio).
        settings: A plain dict validated by :meth:`MinkSettings.from_dict`.
        name: Method name reported in results.
        formulation: ``"soft_return"`` (``mink``, ``mink-posture``; default) or ``"hard"`` (``mink-hard``).
        limits: Joint limits (:mod:`tpik.limits`) as rows of one mink limit; the position limits
            (gain ``configuration_limit_gain``) and the velocity limits when None.

    Raises:
        UnknownSolver: ``settings["solver"]`` is not an installed QP backend.
        InvalidSettings: Unknown key or bad value.
    """

    def __init__(
        self,
        robot: Robot,
        settings: Mapping[str, Any] | None = None,
        name: str = "mink",
        formulation: str = "soft_return",
        limits: Sequence[Limit] | None = None,
    ) -> None:
        if formulation not in FORMULATIONS:
            raise InvalidSettings("mink", f"unknown formulation {formulation!r}; known: {', '.join(FORMULATIONS)}")
        self.robot = robot
        self.name = name
        self.formulation = formulation
        self.settings = MinkSettings.from_dict(settings)
        s = self.settings
        self.reference = ControlReference(gain_cap=s.gain_cap)
        self.tolerance = float(s.tolerance if s.tolerance is not None else BACKENDS[s.solver].tolerance)
        self._qp_kwargs = backend_kwargs(s.solver, s.qp_settings or {})
        self.configuration = mink.Configuration(robot.mj_model)
        nv = robot.nq
        self._limit_rows = SetTaskLimit(nv)
        self.limits: tuple[Limit, ...] = (
            (PositionLimit.from_robot(robot, gain=s.configuration_limit_gain), VelocityLimit.from_robot(robot))
            if limits is None
            else tuple(limits)
        )
        """Joint limits (:mod:`tpik.limits`), as rows of one mink limit (:class:`JointLimits`)."""
        if limits is None:
            # The defaults are mink's own ConfigurationLimit and VelocityLimit
            # (the same rows as self.limits; tests/qp_baseline/test_limits.py compares them).
            velocities = {robot.joint_names[i]: float(robot.v_max[i]) for i in range(nv)}
            own: list[mink.Limit] = [
                mink.ConfigurationLimit(robot.mj_model, gain=s.configuration_limit_gain),
                mink.VelocityLimit(robot.mj_model, velocities),
            ]
        else:
            own = [JointLimits(self.limits)]
        self._limits: list[mink.Limit] = [*own, self._limit_rows]
        velocity = next((lim for lim in self.limits if isinstance(lim, VelocityLimit)), None)
        self._v_max = (velocity or VelocityLimit.from_robot(robot)).v_max  # the answer is clipped into it
        self._bodies: dict[str, int] = {}
        self._hierarchy: Hierarchy | None = None
        self._adapters: list[_Adapter] = []
        self._rows = SetRowBuilder((), nv, self.reference)
        self._evaluation: TaskEvaluation | None = None
        self._return: SetTaskReturn | None = None
        self._no_return: tuple[np.ndarray, np.ndarray] = (np.zeros(0), np.zeros((0, nv)))
        self._safety_bounds: list[tuple[float, float]] = []
        self._tasks: list[mink.Task] = []
        self._posture: mink.PostureTask | None = None
        probe_settings(s.solver, s.qp_settings or {})  # a bad backend setting fails here, not mid-run

    def __repr__(self) -> str:
        return f"MinkSolver(name={self.name!r}, formulation={self.formulation!r}, settings={self.settings})"

    @property
    def posture_target(self) -> np.ndarray | None:
        """The posture task's target [rad] (the start posture), None without a posture task or before a solve."""
        return None if self._posture is None or self._posture.target_q is None else self._posture.target_q.copy()

    def _prepare(self, hierarchy: Hierarchy) -> None:
        """Build the mink tasks of a hierarchy once (rebuilt only for a new hierarchy object)."""
        if hierarchy is self._hierarchy:
            return
        rho = self.settings.level_cost_ratio
        levels = list(hierarchy.levels)
        first_eq = next(
            (k for k, lv in enumerate(levels) if any(not isinstance(t, SetTask) for t in lv.tasks)), len(levels)
        )
        adapters: list[_Adapter] = []
        set_tasks: list[SetTask] = []
        set_costs: list[float] = []
        for k, level in enumerate(levels):
            cost = rho ** (first_eq - k)
            for task in level.tasks:
                if isinstance(task, SetTask):
                    set_tasks.append(task)
                    set_costs.append(cost)
                else:
                    adapters.append(self._adapter(task, cost))
        self._adapters = adapters
        soft = self.formulation == "soft_return"
        self._rows = SetRowBuilder(set_tasks, self.robot.nq, self.reference, hold_at_zero=soft)
        # One pass evaluates every task (set rows and the equality tasks' errors), as for TPIK and HQP.
        self._evaluation = TaskEvaluation([*set_tasks, *(a.task for a in adapters)], self.robot)
        ptr = self._evaluation.eq_ptr.tolist()
        for e, adapter in enumerate(adapters):
            adapter.rows = slice(ptr[e], ptr[e + 1])
        self._return = SetTaskReturn(np.array(set_costs)) if soft and set_tasks else None
        zeros = (np.zeros(len(set_tasks)), np.zeros((len(set_tasks), self.robot.nq)))
        for array in zeros:
            array.flags.writeable = False
        self._no_return = zeros
        self._safety_bounds = [(t.thresholds.safety_lower, t.thresholds.safety_upper) for t in set_tasks]
        self._tasks = [a.mink_task for a in adapters] + ([self._return] if self._return is not None else [])
        self._posture = None  # a new hierarchy (a new run): a new start posture
        if self.settings.posture_cost > 0.0:  # its target: the q of this hierarchy's first solve
            self._posture = mink.PostureTask(self.robot.mj_model, cost=self.settings.posture_cost)
            self._tasks.append(self._posture)
        self._hierarchy = hierarchy

    def _adapter(self, task: Task, cost: float) -> _Adapter:
        frame_kinds: list[tuple[type[Task], str, float, float]] = [
            (PoseTask, "pose", cost, cost),
            (PositionTask, "position", cost, 0.0),
            (OrientationTask, "orientation", 0.0, cost),
        ]
        for cls, kind, pos_cost, rot_cost in frame_kinds:
            if isinstance(task, cls):
                frame = str(task.frame)  # type: ignore[attr-defined]
                body = self.robot.mujoco_body(frame)
                frame_task = mink.FrameTask(
                    body, "body", position_cost=pos_cost, orientation_cost=rot_cost, lm_damping=self.settings.lm_damping
                )
                body_id = int(mujoco.mj_name2id(self.robot.mj_model, mujoco.mjtObj.mjOBJ_BODY, body))
                return _Adapter(task, frame_task, kind, body_id)
        return _Adapter(task, _StateTask(np.full(task.dim, cost)), "state")

    def _update_task(self, adapter: _Adapter, ev: TaskEvaluation, dt: float) -> None:
        r"""Load one equality task's mink task from the evaluated rows (σ̃, σ̇_d of ``ev.eq_out``).

        :math:`r = \dot\sigma_d + K\tilde\sigma` (paper eq. 2, :meth:`ControlReference.equality_rate`);
        a frame task gets the target :math:`p + r\,dt/\alpha` (module docstring).
        """
        task = adapter.task
        rows = ev.eq_out[adapter.rows]
        r = self.reference.equality_rate(task, rows[:, EQ_ERROR], rows[:, EQ_FEEDFORWARD], dt)  # paper eq. 2
        if adapter.kind == "state":
            stask = adapter.mink_task
            assert isinstance(stask, _StateTask)
            stask.error = -r * dt
            stask.jacobian = ev.eq_out[adapter.rows, EQ_JAC:].copy()
            return
        alpha = min(1.0, self.reference.gain(task, dt) * dt)
        data = self.configuration.data
        p, R = data.xpos[adapter.body_id], data.xmat[adapter.body_id].reshape(3, 3)
        scale = dt / alpha
        if adapter.kind == "position":
            p_t, R_t = p + r * scale, R
        elif adapter.kind == "orientation":
            p_t, R_t = p, _so3_exp(r * scale) @ R
        else:
            p_t, R_t = p + r[:3] * scale, _so3_exp(r[3:] * scale) @ R
        ftask = adapter.mink_task
        assert isinstance(ftask, mink.FrameTask)
        ftask.gain = alpha
        ftask.set_target(_frame_target(R_t, p_t))
        if self._posture is not None:
            # mink's examples give the frame and posture tasks the same gain (1: each asks its whole
            # error in one step); the frame task asks α of it here, and so does the posture task.
            self._posture.gain = alpha

    def _update_return(self, ev: TaskEvaluation, sigma: np.ndarray, dt: float) -> list[tuple[int, float, float]]:
        r"""Rows of the return task; returns (task index, reference rate, side) of the tasks it pulls back.

        A task is pulled back when its σ is finite and its reference asks it to move away from a
        threshold: :math:`\dot\sigma_l > 0` or :math:`\dot\sigma_u < 0`. Without a rate
        feed-forward that is σ outside its safety thresholds; with a predicted approach f it
        starts f/K earlier, as the rows of HQP hold it. Its row is the evaluated Jacobian row (the
        one its limit rows use) and the error −rate·dt.
        """
        ret = self._return
        assert ret is not None
        tasks = self._rows.tasks
        bounds = zip(sigma.tolist(), self._safety_bounds, strict=True)
        near = [
            (i, s)
            for i, (s, (lo, hi)) in enumerate(bounds)
            if math.isfinite(s) and (not lo <= s <= hi or tasks[i].rate_feedforward != 0.0)
        ]
        pulled: list[tuple[int, float, float]] = []
        for i, s in near:
            lo, hi = self.reference.set_rates(tasks[i], s, dt)
            if lo > 0.0:
                pulled.append((i, lo, -1.0))
            elif hi < 0.0:
                pulled.append((i, hi, 1.0))
        if not pulled:  # the usual step: no row (read-only zeros, shared between steps)
            ret.error, ret.jacobian = self._no_return
            return []
        error = np.zeros(len(tasks))
        jac = np.zeros((len(tasks), self.robot.nq))
        for i, rate, _ in pulled:
            jac[i] = ev.set_out[i, SET_JAC:]
            error[i] = -rate * dt
        ret.error, ret.jacobian = error, jac
        return pulled

    def solve(self, hierarchy: Hierarchy, kin: Kinematics, dt: float) -> StepResult:
        """One step: build mink's QP at ``kin.q`` and solve it with the configured backend.

        Args:
            hierarchy: The shared hierarchy (only read).
            kin: Kinematics snapshot at the current configuration (only ``kin.q`` is read:
                mink computes its own kinematics).
            dt: Control period [s].

        Returns:
            A :class:`StepResult`; FAILED with zero velocity when the backend finds no solution
            or its step breaks a constraint by more than ``tolerance``; DEGRADED when a task past
            its safety threshold comes back slower than its reference rate.

        Raises:
            tpik.TpikError: A task cannot be evaluated (e.g. a target not set).
        """
        n = self.robot.nq
        if not (math.isfinite(dt) and dt > 0.0):
            return failed(n, f"dt must be finite and > 0, got {dt}")
        result = self._solve_step(hierarchy, kin, dt)
        for limit in self.limits:
            limit.observe(result.qdot)
        return result

    def _solve_step(self, hierarchy: Hierarchy, kin: Kinematics, dt: float) -> StepResult:
        """:meth:`solve` without the limits' :meth:`~tpik.limits.Limit.observe` (dt already checked)."""
        n = self.robot.nq
        t0 = time.perf_counter()
        if self.budget is not None:
            self.budget.start()
        self._prepare(hierarchy)
        self.configuration.update(kin.q)
        if self._posture is not None and self._posture.target_q is None:
            self._posture.set_target(kin.q)  # the start posture
        mkin = MinkKinematics(self.robot, self.configuration, self._bodies)
        ev = self._evaluation
        assert ev is not None
        ev.evaluate(mkin)  # every task at once, on mink's kinematics
        for adapter in self._adapters:
            self._update_task(adapter, ev, dt)
        rows = self._rows.rows(ev, dt)
        self._limit_rows.set_rows(rows.G, rows.h)
        pulled = self._update_return(ev, rows.sigma, dt) if self._return is not None else []
        tb = time.perf_counter()
        problem = mink.build_ik(self.configuration, self._tasks, dt, self.settings.damping, self._limits)
        t1 = time.perf_counter()
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                kwargs = self._budget_kwargs(self.settings.solver, self._qp_kwargs)
                solution = qpsolvers.solve_problem(problem, solver=self.settings.solver, **kwargs)
        except (qpsolvers.QPError, ValueError, ArithmeticError) as exc:  # the backend's own failure
            res = failed(n, f"{self.name} ({self.settings.solver}) raised {type(exc).__name__}: {exc}")
            res.build_time_s, res.solve_time_s = t1 - t0, time.perf_counter() - t1
            return res
        t2 = time.perf_counter()
        result = self._finish(solution, problem, rows, pulled, dt)
        result.build_time_s, result.solve_time_s = t1 - t0, t2 - t1
        result.extras["problem_build_s"] = t1 - tb  # mink.build_ik alone (the rest of build: row updates)
        return result

    def _finish(
        self,
        solution: qpsolvers.Solution,
        problem: qpsolvers.Problem,
        rows: SetRows,
        pulled: list[tuple[int, float, float]],
        dt: float,
    ) -> StepResult:
        n = self.robot.nq
        x = solution.x
        iterations = backend_iterations(solution)
        if not solution.found or x is None or x.shape != (n,) or not np.isfinite(x).all():
            return failed(n, f"{self.name}: QP solver {self.settings.solver} found no solution", iterations=iterations)
        tol = self.tolerance
        if problem.G is not None and problem.h is not None:
            excess = float((problem.G @ x - problem.h).max())
            if excess > tol:
                return failed(
                    n,
                    f"{self.name}: the step breaks its constraints by {excess:.3g} (tolerance {tol:g}, Δq units)",
                    iterations=iterations,
                )
        v_max = self._v_max
        qdot = np.minimum(np.maximum(x / dt, -v_max), v_max)  # mink.solve_ik returns Δq / dt [rad/s]
        tasks = self._rows.tasks
        active: list[str] = []
        if rows.h.size:
            binding = (rows.G @ x) >= rows.h * dt - tol  # a row at its bound: the task is held
            for owner in dict.fromkeys(rows.owner[binding].tolist()):  # first binding row's order
                active.append(tasks[owner].name)
        slow: list[str] = []
        ret = self._return
        for index, rate, side in pulled:
            task = tasks[index]
            if task.name not in active:
                active.append(task.name)
            assert ret is not None
            actual = float(ret.jacobian[index] @ qdot)  # the row the return task pulled with
            if side * (actual - rate) > tol / dt:
                slow.append(task.name)
        extras = {"iterations": iterations, "returning": [tasks[i].name for i, _, _ in pulled]}
        if slow:
            message = f"{self.name}: past their safety threshold, coming back slower than the reference: "
            return StepResult(
                qdot, SolveStatus.DEGRADED, tuple(active), message=message + ", ".join(slow), extras=extras
            )
        return StepResult(qdot, SolveStatus.OK, tuple(active), extras=extras)

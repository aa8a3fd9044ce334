"""Fake tasks with given Jacobians, a reference cascade, and a closed-loop integrator for solver tests."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import pytest

from robots import Kinematics, Robot
from tpik.hierarchy import Hierarchy, Level
from tpik.solver import TpikSettings, TpikSolver
from tpik.step_result import StepResult
from tpik.tasks import SetTask, Task, TaskState, Thresholds


class MatrixTask(Task):
    """Equality task with a fixed Jacobian J and reference (error) e: q̇ should give J q̇ = e."""

    def __init__(self, name: str, jacobian: np.ndarray, error: np.ndarray, gain: float = 1.0) -> None:
        jac = np.atleast_2d(np.asarray(jacobian, dtype=float))
        super().__init__(name, jac.shape[0], gain)
        self.jacobian = jac
        self.error = np.asarray(error, dtype=float).reshape(-1)

    def compute_state(self, kin: Kinematics) -> TaskState:
        return TaskState(np.zeros(self.dim), self.jacobian, self.error.copy(), np.zeros(self.dim))


class BadShapeTask(Task):
    """Returns a Jacobian with one column too many."""

    def __init__(self, name: str = "bad") -> None:
        super().__init__(name, 2, 1.0)

    def compute_state(self, kin: Kinematics) -> TaskState:
        return TaskState(np.zeros(2), np.zeros((2, kin.nq + 1)), np.zeros(2), np.zeros(2))


class JointTargetTask(Task):
    """Equality task σ = q_j (1-based j) driven to ``target`` [rad]."""

    def __init__(self, name: str, joint: int, nq: int, target: float, gain: float = 1.0) -> None:
        super().__init__(name, 1, gain)
        self.joint = joint
        self.target = target
        self._jac = np.zeros((1, nq))
        self._jac[0, joint - 1] = 1.0

    def compute_state(self, kin: Kinematics) -> TaskState:
        return TaskState(np.array([kin.q[self.joint - 1]]), self._jac, np.array([self.target]), np.zeros(1))


class RowSetTask(SetTask):
    """Set-based task with a given value σ and Jacobian row (for mode-selection tests)."""

    def __init__(self, name: str, sigma: float, row: np.ndarray, thresholds: Thresholds, gain: float = 1.0) -> None:
        super().__init__(name, thresholds, gain)
        self.sigma = float(sigma)
        self.row = np.asarray(row, dtype=float)[None, :]

    def compute_value_and_jacobian(self, kin: Kinematics) -> tuple[float, np.ndarray]:
        return self.sigma, self.row


def one_level_each(*tasks: Task) -> Hierarchy:
    """A hierarchy with one task per level, in order."""
    return Hierarchy([Level(f"level_{i}", (t,)) for i, t in enumerate(tasks)])


def dynamic_damping(sigma_min: float, sigma_star: float) -> float:
    """The paper's λ (sec. II-A), written independently of tpik.dls."""
    if sigma_min >= sigma_star:
        return 0.0
    if sigma_min >= sigma_star / 2:
        return math.sqrt(sigma_min * (sigma_star - sigma_min))
    return sigma_star / 2


def svd_dls(M: np.ndarray, r: np.ndarray, vnorm: float, tol: float) -> tuple[np.ndarray, float]:
    """M^# r by damped least squares from the SVD of M (paper's λ, rank-truncated at ``tol``).

    Returns the joint velocity and λ.
    """
    U, s, Vt = np.linalg.svd(M, full_matrices=False)
    sigma_min = float(s.min()) if M.shape[0] <= M.shape[1] else 0.0
    lam = dynamic_damping(sigma_min, float(np.linalg.norm(r)) / vnorm)
    keep = s > tol
    return Vt[keep].T @ ((s[keep] / (s[keep] ** 2 + lam**2)) * (U[:, keep].T @ r)), lam


def reference_cascade(
    levels: list[tuple[np.ndarray, np.ndarray]], variant: str, vnorm: float, tol: float = 1e-6
) -> tuple[np.ndarray, list[float]]:
    """Textbook NSB / SS cascade with SVD-based DLS and projectors, in joint space.

    Returns q̇ before the velocity scaling and λ per level.
    """
    n = levels[0][0].shape[1]
    qdot = np.zeros(n)
    N = np.eye(n)
    lams = []
    for J, x in levels:
        if variant == "nsb":
            M, r = J, x
        else:
            M, r = J @ N, x - J @ qdot
        dq, lam = svd_dls(M, r, vnorm, tol)
        qdot = qdot + (N @ dq if variant == "nsb" else dq)
        _, s2, Vt2 = np.linalg.svd(J @ N, full_matrices=False)
        V = Vt2[s2 > tol]
        N = N - V.T @ V
        lams.append(lam)
    return qdot, lams


def simulate(
    robot: Robot,
    hierarchy: Hierarchy,
    solver: TpikSolver,
    q0: np.ndarray,
    steps: int,
    dt: float = 0.01,
    watch: Callable[[Kinematics], float] | None = None,
) -> tuple[np.ndarray, list[StepResult], np.ndarray]:
    """Pure kinematic closed loop q += q̇ dt; returns final q, results, and ``watch`` per step."""
    q = np.array(q0, dtype=float)
    results = []
    watched = []
    for _ in range(steps):
        kin = robot.kinematics(q)
        if watch is not None:
            watched.append(watch(kin))
        result = solver.solve(hierarchy, kin, dt)
        results.append(result)
        q = q + result.qdot * dt
    if watch is not None:
        watched.append(watch(robot.kinematics(q)))
    return q, results, np.array(watched)


SOLVER_CONFIGS = [
    pytest.param({"variant": "nsb"}, id="nsb"),
    pytest.param({"variant": "ss"}, id="ss"),
    pytest.param({"variant": "nsb", "selection": "fewest_active"}, id="nsb-fewest"),
]


@pytest.fixture(params=SOLVER_CONFIGS)
def solver(request: pytest.FixtureRequest, jaco: Robot) -> TpikSolver:
    """A TPIK solver for each variant / selection rule."""
    return TpikSolver(jaco, TpikSettings.from_dict(request.param), name="tpik-test")

"""The closed loop's accounting: which exceptions are FAILED steps, which abort the run; one status rule."""

from __future__ import annotations

import numpy as np
import pytest

from compare.loop.closed_loop import SOLVER_ERRORS, run_loop, warm_up_solver
from compare.loop.robot_io import JointReading, RobotIO
from compare.loop.settings import LoopSettings
from compare.loop.waypoints import WaypointSchedule
from compare.methods import make_method
from compare.sensing.frames import DepthFrame
from qp_baseline.exceptions import NoSolutionFound
from tests.qp_baseline.helpers import joint_limit_level, position_level, wall_behind_ee
from tpik.exceptions import TargetNotSet
from tpik.hierarchy import Hierarchy, Level
from tpik.step_result import SolverBase, StepResult
from tpik.tasks import PositionTask

DT = 0.01
METHODS = ("tpik", "tpik-paper", "hqp-daqp", "mink", "mink-hard", "mink-posture")


class KinematicIO(RobotIO):
    """q += q̇ dt, no sensor; counts the stop commands."""

    def __init__(self, dt: float, nq: int, q: np.ndarray) -> None:
        self.dt, self.nq = dt, nq
        self.state = {"q": np.array(q, dtype=float), "t": 0.0, "qdot": np.zeros(nq), "stops": 0}

    def now(self) -> float:
        return self.state["t"]

    def read_joints(self) -> JointReading:
        return JointReading(self.state["q"].copy(), self.state["qdot"].copy(), self.state["t"])

    def read_depth(self) -> DepthFrame | None:
        return None

    def send_velocity(self, qdot: np.ndarray) -> None:
        self.state["qdot"] = np.asarray(qdot, dtype=float).copy()

    def wait(self) -> None:
        self.state["q"] = self.state["q"] + self.state["qdot"] * self.dt
        self.state["t"] += self.dt

    def stop(self) -> None:
        self.state["stops"] += 1
        super().stop()


class RaisingSolver(SolverBase):
    """Wraps a solver; raises ``error`` from the ``at``-th solve on."""

    def __init__(self, inner, error: Exception, at: int = 3) -> None:
        self.inner, self.error, self.at, self.calls = inner, error, at, 0
        self.name = inner.name

    def solve(self, hierarchy, kin, dt) -> StepResult:
        self.calls += 1
        if self.calls > self.at:
            raise self.error
        return self.inner.solve(hierarchy, kin, dt)


def _run(jaco, solver, hierarchy, steps: int = 20):
    io = KinematicIO(DT, jaco.nq, q=jaco.home)
    ee0 = jaco.frame_position(jaco.home, "end_effector")
    schedule = WaypointSchedule([ee0 + np.array([0.05, 0.0, 0.0])], ee0, dwell_s=0.0)
    out = run_loop(io, jaco, hierarchy, solver, schedule, LoopSettings(dt=DT, duration_s=steps * DT))
    return io, out


def _ee_hierarchy(jaco) -> Hierarchy:
    return Hierarchy([joint_limit_level(jaco), position_level(np.zeros(3))])


def test_a_bug_in_a_solver_aborts_the_run_with_the_robot_stopped(jaco):
    solver = RaisingSolver(make_method("tpik", jaco), TypeError("unsupported operand"))
    io = KinematicIO(DT, jaco.nq, q=jaco.home)
    with pytest.raises(TypeError, match="unsupported operand"):
        ee0 = jaco.frame_position(jaco.home, "end_effector")
        run_loop(io, jaco, _ee_hierarchy(jaco), solver, WaypointSchedule([], ee0), LoopSettings(dt=DT, duration_s=0.2))
    assert io.state["stops"] >= 1 and not io.state["qdot"].any()
    assert not issubclass(TypeError, SOLVER_ERRORS)


@pytest.mark.parametrize(
    "error", [NoSolutionFound(0, None, "backend gave up"), TargetNotSet("x")], ids=["no-solution", "task-error"]
)
def test_a_solver_domain_error_is_a_failed_step_and_the_fallback_acts(jaco, error):
    solver = RaisingSolver(make_method("hqp-daqp", jaco), error, at=5)
    _, out = _run(jaco, solver, _ee_hierarchy(jaco))
    status = out.steps["status"].tolist()
    assert status[:5] == ["ok"] * 5 and set(status[5:]) == {"failed"}
    assert out.steps["fallback"].tolist() == [False] * 5 + [True] * 15
    assert np.all(out.steps.filter(like="qdot_").to_numpy()[5:] == 0.0)
    assert any(type(error).__name__ in event for event in out.events)


@pytest.mark.parametrize("name", METHODS)
def test_a_task_without_target_raises_the_same_error_from_every_solver(jaco, name):
    """The same ill-posed problem, the same answer: tpik's TargetNotSet, which the loop counts as FAILED."""
    hierarchy = Hierarchy([Level("operational", (PositionTask("link_6_position", "link_6"),))])
    with pytest.raises(TargetNotSet, match="link_6_position"):
        make_method(name, jaco).solve(hierarchy, jaco.kinematics(jaco.home), DT)
    _, out = _run(jaco, make_method(name, jaco), hierarchy, steps=5)
    assert set(out.steps["status"]) == {"failed"} and out.steps["fallback"].all()


@pytest.mark.parametrize("name", METHODS)
def test_one_status_rule_marks_a_missed_return_rate_degraded_for_every_method(jaco, name):
    """The EE starts 5 mm past a wall (K = 10 /s: back at ≥ 0.05 m/s) while its target pulls it on at 0.05 m/s.

    Every method's command is checked by the same rule; ``mink`` (soft return, weighted) and
    ``tpik-paper`` (eqs. 8–9 alone) may come back slower: DEGRADED. Strict-priority methods come
    back at the reference rate: OK unless they report a relaxation of their own.
    """
    kin = jaco.kinematics(jaco.home)
    ee = kin.frame_position("end_effector")
    wall = wall_behind_ee(ee, 0.005, gain=10.0)
    position = PositionTask("position_end_effector", gain=1.0)
    hierarchy = Hierarchy([Level("walls", (wall,)), Level("operational", (position,))])
    io = KinematicIO(DT, jaco.nq, q=jaco.home)
    schedule = WaypointSchedule([ee - np.array([0.05, 0.0, 0.0])], ee, dwell_s=0.0)
    out = run_loop(io, jaco, hierarchy, make_method(name, jaco), schedule, LoopSettings(dt=DT, duration_s=DT))
    status = out.steps["status"].iloc[0]
    sigma = float(out.steps["sigma:wall"].iloc[0])
    qdot = out.steps.filter(like="qdot_").to_numpy()[0]
    rate = float(wall.compute_jacobian(jaco.kinematics(jaco.home))[0] @ qdot)
    reference = 10.0 * (0.0 - sigma)
    assert sigma == pytest.approx(-0.005, abs=1e-9)
    if rate < reference - 1e-3:
        assert status == "degraded"
    if name in ("tpik", "hqp-daqp", "mink-hard"):
        assert rate == pytest.approx(reference, abs=1e-6)
    if name == "mink":
        assert status == "degraded" and 0.0 < rate < reference


def test_deadline_misses_are_flagged_against_the_control_period(jaco):
    class Slow(RaisingSolver):
        def solve(self, hierarchy, kin, dt) -> StepResult:
            self.calls += 1
            result = self.inner.solve(hierarchy, kin, dt)
            if self.calls % 4 == 0:
                import time

                time.sleep(0.012)  # > 10 ms
            return result

    _, out = _run(jaco, Slow(make_method("tpik", jaco), TypeError()), _ee_hierarchy(jaco))
    flagged = out.steps["deadline_miss"].to_numpy()
    assert flagged[3::4].all() and flagged.sum() == 5
    assert (out.steps["solve_time_us"].to_numpy()[flagged] > 1e4).all()


@pytest.mark.parametrize("name", METHODS)
def test_warm_up_solves_before_the_run_without_changing_it(jaco, name):
    hierarchy = _ee_hierarchy(jaco)
    solver = make_method(name, jaco)
    assert warm_up_solver(solver, hierarchy, jaco, jaco.home, DT) == 3
    _, warm = _run(jaco, solver, hierarchy, steps=10)
    _, cold = _run(jaco, make_method(name, jaco), _ee_hierarchy(jaco), steps=10)
    np.testing.assert_allclose(warm.steps.filter(like="qdot_"), cold.steps.filter(like="qdot_"), atol=1e-9)


def test_the_garbage_collector_never_runs_inside_a_timed_solve_and_is_restored_after_it(jaco):
    import gc

    from compare.loop.closed_loop import timed_solve
    from tpik.exceptions import InvalidTaskState
    from tpik.step_result import SolveStatus, StepResult

    seen: list[bool] = []

    class Probe(SolverBase):
        name = "probe"

        def __init__(self, fail: bool) -> None:
            self.fail = fail

        def solve(self, hierarchy, kin, dt):
            seen.append(gc.isenabled())
            if self.fail:
                raise InvalidTaskState("probe")
            return StepResult(qdot=np.zeros(kin.nq), status=SolveStatus.OK)

    kin = jaco.kinematics(jaco.home)
    assert gc.isenabled()
    ok = timed_solve(Probe(False), None, kin, 0.01)  # type: ignore[arg-type]
    failed = timed_solve(Probe(True), None, kin, 0.01)  # type: ignore[arg-type]
    assert seen == [False, False] and gc.isenabled()
    assert ok[1] == SolveStatus.OK and failed[1] == SolveStatus.FAILED

"""One timing rule for every method: the timed solve contains the kinematics the method reads, and
the same budget rule decides whether an answer arrived in time.

The kinematics each method computes are logged (pinocchio's data for HQP, mink's MuJoCo update,
TPIK's compiled chain from ``q``), and so are the loop's two clock reads around each solve; a
method whose kinematics were computed before its window (or after it) breaks the first test. A
fake clock charges a share of the limit to the kinematics: every method must answer at 95 % of
the limit and miss at 105 %, with no share held back from any of them.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from types import SimpleNamespace
from typing import Any

import mink
import numpy as np
import pytest

import compare.loop.closed_loop as closed_loop
import qp_baseline.time_limits as time_limits
import tpik.solver
from compare.loop import deadline
from compare.loop.closed_loop import run_loop, timed_solve
from compare.loop.deadline import MeasuredDeadline
from compare.loop.settings import LoopSettings
from compare.loop.waypoints import WaypointSchedule
from compare.methods import make_method
from robots.robot import Robot
from tests.compare.loop.test_closed_loop import KinematicIO
from tests.qp_baseline.helpers import joint_limit_level, position_level
from tpik.hierarchy import Hierarchy
from tpik.step_result import SolveStatus
from tpik.step_rows import STAGE_KINEMATICS

DT = 0.01
METHODS = ("tpik", "hqp-daqp", "mink", "mink-hard")
KINEMATICS = {"pinocchio", "mujoco", "compiled chain"}


class _Log:
    """Events in call order; ``charge_s`` is added to :attr:`now` at every kinematics event."""

    def __init__(self) -> None:
        self.events: list[str] = []
        self.now = 0.0
        self.charge_s = 0.0

    def kinematics(self, kind: str) -> None:
        self.events.append(kind)
        self.now += self.charge_s

    def clock(self) -> float:
        return self.now


@pytest.fixture
def log(monkeypatch: pytest.MonkeyPatch) -> Iterator[_Log]:
    """Every kinematics computation logged: pinocchio's, mink's MuJoCo update, TPIK's compiled chain."""
    log = _Log()
    compute, update, step = Robot._compute_pinocchio, mink.Configuration.update, tpik.solver.tpik_step

    def pinocchio(self: Robot, q: np.ndarray) -> None:
        log.kinematics("pinocchio")
        compute(self, q)

    def mujoco(self: mink.Configuration, q: np.ndarray | None = None) -> None:
        log.kinematics("mujoco")
        update(self, q)

    def compiled(*args: Any) -> None:
        if args[-7] == STAGE_KINEMATICS:  # tpik_step(q, *buffers, stage, dt, flags, reals, max_exhaustive, iout, fout)
            log.kinematics("compiled chain")
        step(*args)

    monkeypatch.setattr(Robot, "_compute_pinocchio", pinocchio)
    monkeypatch.setattr(mink.Configuration, "update", mujoco)
    monkeypatch.setattr(tpik.solver, "tpik_step", compiled)
    yield log


def _hierarchy(jaco: Robot) -> Hierarchy:
    return Hierarchy([joint_limit_level(jaco), position_level(np.zeros(3))])


def _windows(events: list[str]) -> list[list[str]]:
    """The events between the two clock reads of each timed solve."""
    marks = [i for i, e in enumerate(events) if e == "clock"]
    assert len(marks) % 2 == 0
    return [events[a + 1 : b] for a, b in zip(marks[::2], marks[1::2], strict=True)]


@pytest.mark.parametrize("name", METHODS)
def test_every_methods_timed_solve_contains_the_kinematics_it_reads(jaco, log, monkeypatch, name):
    """In each step, exactly one kinematics computation falls inside the solve's timed window."""
    solver = make_method(name, jaco)
    clock = SimpleNamespace(perf_counter=time.perf_counter)

    def perf_counter_ns() -> int:
        log.events.append("clock")
        return time.perf_counter_ns()

    clock.perf_counter_ns = perf_counter_ns
    monkeypatch.setattr(closed_loop, "time", clock)
    io = KinematicIO(DT, jaco.nq, q=jaco.home)
    ee0 = jaco.frame_position(jaco.home, "end_effector")
    schedule = WaypointSchedule([ee0 + np.array([0.05, 0.0, 0.0])], ee0, dwell_s=0.0)
    log.events.clear()
    out = run_loop(io, jaco, _hierarchy(jaco), solver, schedule, LoopSettings(dt=DT, duration_s=5 * DT))
    windows = _windows(log.events)
    assert len(windows) == 5 and set(out.steps["status"]) <= {"ok", "degraded"}
    own = {"tpik": "compiled chain", "hqp-daqp": "pinocchio"}.get(name, "mujoco")
    for window in windows:
        assert [e for e in window if e in KINEMATICS] == [own]


@pytest.mark.parametrize("name", ("tpik", "hqp-daqp", "mink"))
@pytest.mark.parametrize("used", (0.95, 1.05))
def test_one_budget_rule_every_method_answers_within_the_limit_and_misses_past_it(jaco, log, monkeypatch, name, used):
    """The kinematics are charged ``used`` × the limit on a fake CPU clock, the rest of the call nothing.

    At 95 % every method answers (no share of the budget is kept from a QP backend); at 105 %
    every step is a FAILED deadline miss, whichever part of the method noticed it.
    """
    limit = 0.005
    monkeypatch.setitem(deadline.CLOCKS, "cpu", log.clock)
    monkeypatch.setitem(time_limits.CLOCKS, "cpu", log.clock)
    hierarchy = _hierarchy(jaco)
    ee = jaco.frame_position(jaco.home, "end_effector")
    hierarchy.tasks[-1].set_target(ee + np.array([0.3, -0.2, 0.1]))  # far: the velocity box binds
    guard = MeasuredDeadline(make_method(name, jaco), limit, clock="cpu", exclude_steal=False)
    log.charge_s = used * limit
    log.events.clear()
    qdot, status, _, message, missed, _ = timed_solve(guard, hierarchy, jaco.kinematics(jaco.home), DT)
    assert len([e for e in log.events if e in KINEMATICS]) == 1  # the charge was made, once
    if used < 1.0:
        assert status is not SolveStatus.FAILED and not missed, message
        assert np.abs(qdot).max() > 0.0
    else:
        assert status is SolveStatus.FAILED and missed
        assert not qdot.any()

"""A simulated run is a function of (config, seed): a slow or loaded machine changes no trajectory."""

from __future__ import annotations

import subprocess
import sys
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest

from compare.config import load_config
from compare.run import run_method
from compare.scenarios.random_scenario import realize

ROOT = Path(__file__).resolve().parents[2]
TRAJECTORY = ["q_", "qdot_", "status", "dist_true:", "fallback"]


@contextmanager
def _busy_cpus(n: int = 2):
    """``n`` processes spinning on the CPU for the duration of the block."""
    procs = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(n)]
    try:
        yield
    finally:
        for p in procs:
            p.kill()
            p.wait()


def _config(**overrides: object):
    base = {"scenario.seed": 3, "scenario.duration_s": 4.0, "scenario.sensing": "geometric"}
    config, _ = load_config(ROOT / "configs" / "random.toml", base | overrides)
    return realize(config, config.load_robot())


def _columns(steps):
    return [c for c in steps.columns if any(c.startswith(p) for p in TRAJECTORY)]


@pytest.mark.parametrize("method", ["tpik", "hqp-daqp", "mink"])
def test_a_much_slower_loaded_machine_changes_no_trajectory_and_the_misses_are_reported(jaco, method):
    reference = run_method(_config(), method, jaco)
    with _busy_cpus():
        slow = run_method(_config(**{"solver_limit.time_limit_s": 1e-6}), method, jaco)
    a, b = reference["steps"], slow["steps"]
    for column in _columns(a):
        np.testing.assert_array_equal(a[column].to_numpy(), b[column].to_numpy(), err_msg=column)
    assert slow["summary"]["failures"] == reference["summary"]["failures"] == 0
    assert slow["summary"]["solver_limit"]["time_limit_s"] is None  # not enforced in simulation
    # A miss is reported (a solve longer than the control period), never acted on.
    late = b["solve_time_us"].to_numpy() > 1e6 * 0.01
    np.testing.assert_array_equal(b["deadline_miss"].to_numpy(), late)
    assert slow["summary"]["deadline_misses"] == int(late.sum())


def test_with_realtime_the_limit_replaces_late_answers_by_the_fallback(jaco):
    enforced = run_method(_config(**{"solver_limit.time_limit_s": 1e-6, "loop.realtime": True}), "tpik", jaco)
    m = enforced["summary"]
    steps = enforced["steps"]
    assert m["solver_limit"]["time_limit_s"] == 1e-6
    assert m["deadline_misses"] == m["failures"] == m["fallbacks"] == len(steps)
    assert steps["fallback"].all() and steps["deadline_miss"].all()
    assert np.all(steps[[f"qdot_{j}" for j in range(1, 8)]].to_numpy() == 0.0)  # the zero fallback

"""Process warm-up: once per process and method, on a throwaway copy that leaves the run unchanged."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import robots
from compare.config import load_config, parse_config
from compare.loop import warmup
from compare.run import run_method
from compare.scenarios.random_scenario import realize
from tpik.step_result import SolverBase

CONFIGS = Path(__file__).resolve().parents[3] / "configs"
TIMING = ["solve_time_us", "deadline_miss"]


@pytest.fixture(scope="module")
def robot() -> robots.Robot:
    return robots.load(robots.DEFAULT_ROBOT)


def _config(robot: robots.Robot, method: str):
    config, _ = load_config(CONFIGS / "random.toml")
    data = config.model_dump(mode="python")
    data["scenario"].update(duration_s=2.5, sensing="geometric", seed=3)
    data["methods"] = {"names": [method], "settings": {}}
    data["solver_limit"] = {"enabled": False}  # no CPU-time verdicts: the two runs must be equal
    return realize(parse_config(data), robot)


@pytest.mark.parametrize("method", ["tpik", "hqp-daqp"])
def test_the_warm_up_runs_once_per_process_and_leaves_the_run_unchanged(robot, method, monkeypatch):
    monkeypatch.setattr(warmup, "_WARM", set())
    calls: list[str] = []
    real = warmup.make_method

    def counting(name, *a, **k):
        calls.append(name)
        return real(name, *a, **k)

    monkeypatch.setattr(warmup, "make_method", counting)
    config = _config(robot, method)
    cold = run_method(config, method, robot)  # warms up first (a throwaway solver)
    warm = run_method(config, method, robot)  # already warm: no second throwaway solver
    assert calls == [method]
    assert cold["summary"]["warmup_steps"] == warm["summary"]["warmup_steps"] == 3
    a, b = cold["steps"].drop(columns=TIMING), warm["steps"].drop(columns=TIMING)
    pd.testing.assert_frame_equal(a, b)
    sigma = a[[c for c in a.columns if c.startswith("active:")]].to_numpy()
    assert sigma.any(), "no set task was active: the comparison would not cover the active branches"


def test_the_warm_up_solves_with_the_set_tasks_inactive_active_and_past_safety(robot, monkeypatch):
    monkeypatch.setattr(warmup, "_WARM", set())
    seen: list[int] = []
    real = warmup.make_method

    class Spy(SolverBase):
        def __init__(self, inner):
            self.inner, self.name = inner, inner.name

        def solve(self, hierarchy, kin, dt):
            result = self.inner.solve(hierarchy, kin, dt)
            seen.append(len(result.active_set))
            return result

    monkeypatch.setattr(warmup, "make_method", lambda *a, **k: Spy(real(*a, **k)))
    config = _config(robot, "tpik")
    q0 = np.array(config.scenario.start_q)
    assert warmup.warm_up_process(config, "tpik", robot, q0) == len(seen) == 9
    assert warmup.warm_up_process(config, "tpik", robot, q0) == 0  # once per process
    n = len(seen) // 3
    assert max(seen[n:]) > max(seen[:n])  # the obstacles in the activation band activate their tasks


def test_the_warm_up_loads_the_loops_compiled_sigma_in_a_fresh_process():
    """The first control step of a run loads no kernel of the loop's σ: the warm-up did (a process of its own)."""
    code = (
        "import robots; from tests.compare.loop.test_warmup import _config; "
        "from compare.loop._sigma_kernel import set_task_sigmas; from compare.loop.warmup import warm_up_process; "
        "r = robots.load(robots.DEFAULT_ROBOT); c = _config(r, 'tpik'); "
        "before = len(set_task_sigmas.signatures); warm_up_process(c, 'tpik', r, r.home.copy()); "
        "print(before, len(set_task_sigmas.signatures))"
    )
    root = Path(__file__).resolve().parents[3]
    run = [sys.executable, "-c", code]
    out = subprocess.run(run, capture_output=True, text=True, timeout=300, cwd=root, check=True)
    assert out.stdout.split() == ["0", "1"]

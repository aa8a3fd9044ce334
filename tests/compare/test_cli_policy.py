"""CLI: a bug in a solver is not a solver failure (non-zero exit, traceback in the log); reports show the accounting."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import pytest
from typer.testing import CliRunner

import compare.run
from compare.cli import app
from tpik.step_result import SolverBase

CONFIGS = Path(__file__).resolve().parents[2] / "configs"


class _Buggy(SolverBase):
    """A solver whose solve has a bug (TypeError) from the 5th call on."""

    def __init__(self, inner) -> None:
        self.inner, self.name, self.calls = inner, inner.name, 0

    def solve(self, hierarchy, kin, dt):
        self.calls += 1
        if self.calls > 5:
            return self.inner.solve(hierarchy, kin, "0.01")  # the bug: dt as a string
        return self.inner.solve(hierarchy, kin, dt)


def test_a_solver_raising_type_error_makes_run_exit_non_zero_with_the_traceback_logged(tmp_path, monkeypatch, caplog):
    make = compare.run.make_method

    def buggy_make(name, robot, settings=None):
        solver = make(name, robot, settings)
        return _Buggy(solver) if name == "hqp-daqp" else solver

    monkeypatch.setattr(compare.run, "make_method", buggy_make)
    out = tmp_path / "run"
    args = ["run", str(CONFIGS / "case1.toml"), "--duration", "0.3", "--sensing", "geometric", "--out", str(out)]
    with caplog.at_level(logging.ERROR, logger="compare.run"):
        result = CliRunner().invoke(app, [*args, "-q", "--no-plots", "-m", "tpik", "-m", "hqp-daqp"])
    assert result.exit_code != 0
    summary = json.loads((out / "summary.json").read_text())
    assert "TypeError" in summary["errors"]["hqp-daqp"]
    assert "tpik" in summary["methods"]  # the other method's results are kept
    record = next(r for r in caplog.records if "hqp-daqp" in r.getMessage())
    assert record.exc_info is not None and record.exc_info[0] is TypeError  # logged with its traceback
    assert "Traceback" in caplog.text


@pytest.mark.slow
def test_ablation_runs_every_deviation_on_disjoint_seeds_and_reports_the_statistics(tmp_path):
    out = tmp_path / "ablation"
    args = ["ablation", str(CONFIGS / "random.toml"), "--n", "2", "--workers", "1", "--seed", "100000"]
    result = CliRunner().invoke(app, [*args, "--duration", "1", "--out", str(out)])
    assert result.exit_code == 0, result.output
    seeds = sorted(json.loads((p / "summary.json").read_text())["seed"] for p in (out / "runs").iterdir())
    assert seeds == [100000, 100001]
    table = json.loads((out / "ablation.json").read_text())
    from tpik.solver import DEVIATIONS

    assert set(table["methods"]) == {"tpik", "tpik-paper"} | {f"tpik-no-{d}" for d in DEVIATIONS}
    for row in table["methods"].values():
        assert set(row["limit_or_wall_violation"]) == {"count", "runs", "rate", "ci95"}
        assert row["limit_or_wall_violation"]["runs"] == 2
    summary = json.loads((out / "sweep_summary.json").read_text())
    assert "tpik vs tpik-paper" in summary["paired"]
    for m in summary["methods"].values():
        assert set(m["status_steps"]) == {"ok", "degraded", "failed"} and m["warmup_steps"] == 2 * 3
    report = (out / "sweep_report.md").read_text()
    assert "Wilson 95 %" in report and "exact McNemar" in report and "Step accounting" in report
    assert "McNemar" in (out / "ablation.md").read_text()


def test_the_harness_renders_headless_without_mujoco_gl_set():
    """Without MUJOCO_GL MuJoCo's GLFW default aborts a headless process (no traceback, exit 134)."""
    import os
    import subprocess
    import sys

    env = {k: v for k, v in os.environ.items() if k not in ("MUJOCO_GL", "DISPLAY", "PYOPENGL_PLATFORM")}
    code = "import compare.cli, mujoco; print(mujoco.GLContext.__module__)"  # the backend MuJoCo chose
    done = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0 and done.stdout.strip() == "mujoco.egl", done.stderr[-2000:]


def test_llvmpipe_renders_in_the_calling_thread_unless_told_otherwise():
    """The harness asks Mesa's software renderer for no worker threads; a user's own setting stands."""
    import os
    import subprocess
    import sys

    env = {k: v for k, v in os.environ.items() if k != "LP_NUM_THREADS"}
    code = "import compare, os; print(os.environ['LP_NUM_THREADS'])"
    for given, expected in ((None, "0"), ("3", "3")):
        run_env = env if given is None else {**env, "LP_NUM_THREADS": given}
        done = subprocess.run([sys.executable, "-c", code], env=run_env, capture_output=True, text=True, timeout=120)
        assert done.returncode == 0 and done.stdout.strip() == expected, done.stderr[-2000:]

"""Re-timing deadline misses: a rerun reaches the missed state, copies of the method are timed there."""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from compare.analysis.metrics import misses_cell
from compare.analysis.results import (
    CONFIG_FILE,
    STEPS_DIR,
    SUMMARY_FILE,
    load_steps,
    safe_name,
    write_sweep_summary,
)
from compare.campaign.miss_recheck import RECHECK_FILE, StepProbe, _ProbeDone, find_misses, recheck_sweep
from compare.cli import app
from compare.config import load_config
from compare.loop.deadline import MeasuredDeadline
from compare.run import run_scenario
from tpik.step_result import SolverBase, SolveStatus, StepResult

ROOT = Path(__file__).resolve().parents[3]
LIMIT_S = 0.005


class _CountingSolver(SolverBase):
    """Spins on the thread's CPU clock for ``busy_s`` per call and counts its calls (its own state)."""

    name = "counting"

    def __init__(self, nq: int, busy_s: float) -> None:
        self.nq, self.busy_s, self.calls = nq, busy_s, 0

    def solve(self, hierarchy, kin, dt) -> StepResult:
        self.calls += 1
        end = time.thread_time() + self.busy_s
        while time.thread_time() < end:
            pass
        return StepResult(np.zeros(self.nq), SolveStatus.OK)


@pytest.fixture(scope="module")
def setup():
    config, _ = load_config(ROOT / "configs" / "random.toml")
    robot = config.load_robot()
    return robot, config.build_hierarchy(robot)


@pytest.mark.parametrize(("busy_s", "late"), [(0.0, False), (2 * LIMIT_S, True)])
def test_probe_times_copies_at_its_step_and_leaves_the_method_alone(setup, busy_s, late):
    robot, hierarchy = setup
    method = _CountingSolver(robot.nq, busy_s)
    guarded = MeasuredDeadline(method, LIMIT_S)
    probe = StepProbe(guarded, method, robot, step=1, replays=3)
    q = robot.home.copy()
    first = probe.solve(hierarchy, robot.kinematics(q), 0.01)  # step 0: passed through
    assert first.status is (SolveStatus.FAILED if late else SolveStatus.OK)
    with pytest.raises(_ProbeDone):
        probe.solve(hierarchy, robot.kinematics(q), 0.01)
    assert method.calls == 2  # the replays ran on copies
    assert probe.rerun_missed is late
    assert len(probe.replay_us) == 3
    if late:
        assert min(probe.replay_us) > LIMIT_S * 1e6
    else:
        assert max(probe.replay_us) < LIMIT_S * 1e6
    np.testing.assert_array_equal(probe.q, q)


def _sweep_with_one_run(tmp_path: Path, method: str, duration_s: float = 0.5, **limit: object) -> Path:
    """A sweep directory of one short run (seed 7), written in-process."""
    overrides: dict[str, object] = {
        "scenario.seed": 7,
        "scenario.duration_s": duration_s,
        "scenario.sensing": "geometric",
        "methods.names": [method],
        "loop.realtime": True,
    }
    overrides.update({f"solver_limit.{k}": v for k, v in limit.items()})
    config, text = load_config(ROOT / "configs" / "random.toml", overrides)
    out = tmp_path / "sweep"
    (out / "runs").mkdir(parents=True)
    (out / CONFIG_FILE).write_text(text, encoding="utf-8")
    run_scenario(config, out / "runs" / "00000", config_text=text, progress=False, make_plots=False)
    write_sweep_summary(out)
    return out


def _mark_miss(run_dir: Path, method: str, row: int, shift_q: float = 0.0) -> None:
    steps = load_steps(run_dir, method)
    steps.loc[row, "deadline_miss"] = True
    steps.loc[row, "q_1"] = steps.loc[row, "q_1"] + shift_q
    steps.to_parquet(run_dir / STEPS_DIR / f"{safe_name(method)}.parquet")
    summary = json.loads((run_dir / SUMMARY_FILE).read_text())
    summary["methods"][method]["deadline_misses"] = 1
    (run_dir / SUMMARY_FILE).write_text(json.dumps(summary))


def test_a_miss_the_method_does_not_reproduce_is_not_reproduced(tmp_path):
    out = _sweep_with_one_run(tmp_path, "hqp-daqp")
    run_dir = out / "runs" / "00000"
    assert find_misses(out) == []  # a clean run: nothing to recheck
    _mark_miss(run_dir, "hqp-daqp", 20)
    misses = find_misses(out)
    assert [(m.method, m.step, m.seed) for m in misses] == [("hqp-daqp", 20, 7)]
    result = recheck_sweep(out, replays=3)
    (entry,) = result["misses"]
    assert entry["state_matches"] is True  # the rerun reached the recorded state bit for bit
    assert entry["rerun_missed"] is False
    assert len(entry["replay_us"]) == 3 and max(entry["replay_us"]) < LIMIT_S * 1e6
    assert entry["verdict"] == "not_reproduced"
    stats = result["methods"]["hqp-daqp"]
    assert stats == {**stats, "misses": 1, "rechecked": 1, "reproduced": 0, "not_reproduced": 1, "unverified": 0}
    on_disk = json.loads((out / RECHECK_FILE).read_text())
    assert on_disk["methods"] == result["methods"]
    assert json.loads((out / "sweep_summary.json").read_text())["methods"]["hqp-daqp"]["deadline_recheck"] == stats


def test_a_rerun_that_does_not_reach_the_recorded_state_is_unverified(tmp_path):
    out = _sweep_with_one_run(tmp_path, "tpik")
    _mark_miss(out / "runs" / "00000", "tpik", 10, shift_q=1e-9)
    (entry,) = recheck_sweep(out, replays=2)["misses"]
    assert entry["state_matches"] is False and entry["verdict"] == "unverified"


def test_earlier_misses_are_made_again_so_that_the_rerun_follows_the_recorded_run(tmp_path):
    # Two misses marked on a run that had none: the first is re-timed on the recorded state; making
    # the first a miss in the rerun (zero velocity there) leaves the recorded trajectory, so the
    # second's state differs: the rerun did force it.
    out = _sweep_with_one_run(tmp_path, "tpik")
    run_dir = out / "runs" / "00000"
    _mark_miss(run_dir, "tpik", 10)
    _mark_miss(run_dir, "tpik", 20)
    first, second = recheck_sweep(out, replays=2)["misses"]
    assert (first["step"], first["earlier_misses"], first["verdict"]) == (10, 0, "not_reproduced")
    assert (second["step"], second["earlier_misses"], second["verdict"]) == (20, 1, "unverified")


def test_misses_the_method_cost_causes_are_reproduced(tmp_path):
    # A 1 µs limit: every solve is late in the run, in its rerun and in every replay. Step 4's
    # rerun makes steps 0-3 misses again and reaches the recorded state exactly.
    out = _sweep_with_one_run(tmp_path, "tpik", duration_s=0.05, time_limit_s=1e-6)
    steps = load_steps(out / "runs" / "00000", "tpik")
    assert steps["deadline_miss"].all() and len(steps) == 5
    result = recheck_sweep(out, replays=2)
    assert [m["step"] for m in result["misses"]] == [0, 1, 2, 3, 4]
    assert all(m["state_matches"] and m["rerun_missed"] for m in result["misses"])
    assert {m["verdict"] for m in result["misses"]} == {"reproduced"}
    assert result["methods"]["tpik"]["reproduced"] == 5


def test_cli_rechecks_writes_and_the_report_shows_it(tmp_path):
    out = _sweep_with_one_run(tmp_path, "tpik")
    _mark_miss(out / "runs" / "00000", "tpik", 10)
    result = CliRunner().invoke(app, ["recheck-misses", str(out), "--replays", "2"])
    assert result.exit_code == 0, result.output
    assert (out / RECHECK_FILE).exists()
    assert "re-timed 1: 0 reproduced" in (out / "sweep_report.md").read_text()


def test_sweep_recheck_misses_flag_rechecks_after_the_sweep(tmp_path):
    config = tmp_path / "limit.toml"
    text = (ROOT / "configs" / "random.toml").read_text(encoding="utf-8")
    config.write_text(text + "\n[solver_limit]\ntime_limit_s = 1e-6\n\n[loop]\nrealtime = true\n", encoding="utf-8")
    out = tmp_path / "sweep"
    args = ["sweep", str(config), "--n", "1", "--workers", "1", "--duration", "0.03", "-m", "tpik"]
    result = CliRunner().invoke(app, [*args, "--out", str(out), "--recheck-misses"])
    assert result.exit_code == 0, result.output
    stats = json.loads((out / "sweep_summary.json").read_text())["methods"]["tpik"]["deadline_recheck"]
    assert stats["misses"] == stats["rechecked"] == stats["reproduced"] == 3
    assert "re-timed 3: 3 reproduced" in (out / "sweep_report.md").read_text()


def test_misses_cell_names_steal_and_rechecks():
    m = {"deadline_misses": 3, "deadline_steal_excused": {"steps": 1}, "deadline_recheck": {"rechecked": 3}}
    assert misses_cell(m) == "3 (+1 steal); re-timed 3: 0 reproduced"
    assert misses_cell({"deadline_misses": 0, "deadline_recheck": {"rechecked": 0}}) == "0"


def test_cli_on_a_directory_that_is_not_a_sweep_is_one_line(tmp_path):
    result = CliRunner().invoke(app, ["recheck-misses", str(tmp_path)])
    assert result.exit_code == 2
    assert "not a sweep directory" in result.output and "Traceback" not in result.output

"""Up-front checks: an unusable output directory or a full disk is one line before the first step."""

from __future__ import annotations

import re
from pathlib import Path

import pandas as pd
import pytest
from typer.testing import CliRunner

import compare.analysis.preflight as preflight
import robots
from compare.analysis.exceptions import OutputUnusable
from compare.analysis.preflight import check_output_dir
from compare.cli import app
from compare.config import load_config
from compare.run import expected_run_bytes

CONFIGS = Path(__file__).resolve().parents[3] / "configs"
SHORT = ["--sensing", "geometric", "--no-plots", "-q"]


def test_a_directory_that_cannot_be_written_is_named_with_the_reason():
    with pytest.raises(OutputUnusable, match=r"^cannot write to /sys: Permission denied$"):
        check_output_dir(Path("/sys"))  # read-only for root too


def test_a_directory_that_cannot_be_created_is_named_with_the_reason(tmp_path):
    (tmp_path / "file").write_text("x")
    with pytest.raises(OutputUnusable, match=r"^cannot create .*/file/out: Not a directory$"):
        check_output_dir(tmp_path / "file" / "out")
    with pytest.raises(OutputUnusable, match=r"file is a file, not a directory$"):
        check_output_dir(tmp_path / "file")


def test_too_little_free_space_is_refused_with_the_sizes(tmp_path, monkeypatch):
    monkeypatch.setattr(preflight, "free_bytes", lambda path: 50_000_000)
    check_output_dir(tmp_path, 10_000_000)  # fits, with the reserve
    with pytest.raises(OutputUnusable, match=r"about 100 MB needed, 50 MB free$"):
        check_output_dir(tmp_path, 100_000_000, "the results")


def _forbid_simulation(monkeypatch):
    def no_step(*args, **kwargs):
        raise AssertionError("a control step ran before the up-front check refused")

    monkeypatch.setattr("compare.run.run_method", no_step)
    monkeypatch.setattr("compare.campaign.executors.run_job", no_step)


def test_run_on_a_full_disk_is_one_line_and_exit_2_before_the_first_step(tmp_path, monkeypatch):
    _forbid_simulation(monkeypatch)
    monkeypatch.setattr(preflight, "free_bytes", lambda path: 1_000)
    out = tmp_path / "R"
    args = ["run", str(CONFIGS / "case1.toml"), "--out", str(out), "-m", "tpik", "--duration", "0.3", *SHORT]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 2, result.output
    assert result.output.startswith("error: not enough disk space in") and result.output.count("\n") == 1
    assert not (out / "summary.json").exists()


def test_sweep_into_an_unwritable_directory_is_one_line_and_exit_2(monkeypatch):
    _forbid_simulation(monkeypatch)
    args = ["sweep", str(CONFIGS / "random.toml"), "--n", "2", "--out", "/sys/sweep", "--workers", "1"]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 2
    assert re.fullmatch(r"error: cannot create /sys/sweep: [A-Z][a-z ]+\n", result.output), result.output


def test_sweep_on_a_full_disk_names_the_pairs_to_run(tmp_path, monkeypatch):
    _forbid_simulation(monkeypatch)
    monkeypatch.setattr(preflight, "free_bytes", lambda path: 1_000)
    args = ["sweep", str(CONFIGS / "random.toml"), "--n", "3", "--out", str(tmp_path / "S"), "-m", "tpik"]
    result = CliRunner().invoke(app, [*args, "--workers", "1", "--duration", "2"])
    assert result.exit_code == 2
    assert "not enough disk space" in result.output and "for 3 (run, method) pairs" in result.output


def test_the_size_estimate_bounds_a_real_run_from_above(tmp_path):
    """The prediction from length and rate is above what a run writes, and not wildly so."""
    out = tmp_path / "run"
    args = ["run", str(CONFIGS / "random.toml"), "--out", str(out), "-m", "tpik", "-m", "hqp-daqp", *SHORT]
    result = CliRunner().invoke(app, [*args, "--duration", "2"])
    assert result.exit_code == 0, result.output
    written = sum(p.stat().st_size for p in out.rglob("*") if p.is_file())
    steps = pd.read_parquet(out / "steps" / "tpik.parquet")
    config, _ = load_config(CONFIGS / "random.toml", {"scenario.duration_s": 2.0})
    jaco = robots.load("jaco2")
    hierarchy = config.build_hierarchy(jaco)
    n_obstacles = sum(t.name.startswith("obstacle") for t in hierarchy.set_tasks)
    assert preflight.step_columns(jaco.nq, len(hierarchy.set_tasks), n_obstacles) == steps.shape[1]
    predicted = expected_run_bytes(config, jaco, 2, plots=False)
    assert written < predicted < 2 * written

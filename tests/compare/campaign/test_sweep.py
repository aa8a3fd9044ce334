"""Sweeps: N runs on a process pool produce N results and a summary; a rerun skips finished runs."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from typer.testing import CliRunner

from compare.campaign.random_scenario import realize
from compare.cli import app
from compare.config import load_config

CONFIGS = Path(__file__).resolve().parents[3] / "configs"


@pytest.mark.slow
def test_sweep_runs_four_seeds_then_skips_them(tmp_path):
    out = tmp_path / "sweep"
    args = [
        "sweep",
        str(CONFIGS / "random.toml"),
        "--n",
        "4",
        "--workers",
        "2",
        "--out",
        str(out),
        "--duration",
        "3",
        "-m",
        "tpik",
        "-m",
        "hqp-daqp",
    ]
    first = CliRunner().invoke(app, args)
    assert first.exit_code == 0, first.output
    runs = sorted((out / "runs").iterdir())
    assert len(runs) == 4
    seeds = [json.loads((r / "summary.json").read_text())["seed"] for r in runs]
    assert seeds == [0, 1, 2, 3]
    summary = json.loads((out / "sweep_summary.json").read_text())
    assert summary["runs"] == 4 and set(summary["methods"]) == {"tpik", "hqp-daqp"}
    plant = {"sensing": "geometric", "simulation": "dynamic", "drive": "decoupled", "drive_bandwidth_rad_s": 100.0}
    assert summary["campaign"]["plant"] == plant
    report = (out / "sweep_report.md").read_text()
    assert "- plant: dynamic simulation, decoupled joint drive (λ = 100 rad/s), geometric sensing" in report
    stamps = [(r / "summary.json").stat().st_mtime_ns for r in runs]

    again = CliRunner().invoke(app, args)
    assert again.exit_code == 0, again.output
    assert [(r / "summary.json").stat().st_mtime_ns for r in runs] == stamps  # nothing redone


def test_random_scenarios_are_reproducible_and_differ_by_seed():
    config, _ = load_config(CONFIGS / "random.toml")
    a = realize(config)
    b = realize(config)
    c = realize(config.model_copy(update={"scenario": config.scenario.model_copy(update={"seed": 1})}))
    assert a == b
    assert a.waypoints.positions != c.waypoints.positions
    assert a.scenario.start_q != c.scenario.start_q
    lo, hi = config.random.workspace_lower, config.random.workspace_upper
    for p in a.waypoints.positions:
        assert all(lo[k] <= p[k] <= hi[k] for k in range(3))
    assert len(a.person.keyframes) > 1

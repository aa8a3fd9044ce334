"""A sweep with the verdict on: per-run labels, violations by label, and the report's section."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from typer.testing import CliRunner

from compare.cli import app

CONFIGS = Path(__file__).resolve().parents[3] / "configs"


@pytest.mark.slow
def test_sweep_with_oracle_splits_obstacle_violations(tmp_path):
    out = tmp_path / "sweep"
    base = ["sweep", str(CONFIGS / "random.toml"), "--n", "2", "--workers", "1", "--out", str(out)]
    base += ["--duration", "4", "-m", "tpik"]
    assert CliRunner().invoke(app, base).exit_code == 0  # first without the oracle
    run0 = out / "runs" / "00000" / "summary.json"
    assert "oracle" not in json.loads(run0.read_text())
    # The oracle is part of the sweep's configuration: adding it to a finished sweep is refused ...
    refused = CliRunner().invoke(app, [*base, "--oracle"])
    assert refused.exit_code == 2 and "oracle.enabled false → true" in refused.output
    assert "oracle" not in json.loads(run0.read_text())  # ... and nothing was touched
    res = CliRunner().invoke(app, [*base, "--oracle", "--overwrite"])  # on purpose: the runs are redone
    assert res.exit_code == 0, res.output
    for run in sorted((out / "runs").iterdir()):
        summary = json.loads((run / "summary.json").read_text())
        oracle = summary["oracle"]
        assert oracle["label"] in ("avoidable", "unavoidable", "undecided")
        assert oracle["held_safety"] is (oracle["label"] == "avoidable") and oracle["min_distance_m"] > 0
        assert oracle["witnesses"] and (oracle["witness"] in oracle["witnesses"] or oracle["witness"] is None)
        assert list((run / "oracle").glob("*.json"))  # cached
        tpik = summary["methods"]["tpik"]
        episodes = tpik["obstacles"]["violations"]
        expected = {
            label: episodes if label == oracle["label"] else 0 for label in ("avoidable", "unavoidable", "undecided")
        }
        assert tpik["obstacle_violations"] == expected
    sweep = json.loads((out / "sweep_summary.json").read_text())
    assert sweep["oracle"]["runs"] == 2
    split = sweep["methods"]["tpik"]["obstacle_violations"]
    assert set(split["avoidable"]) == {"count", "runs", "rate", "ci95"} and split["avoidable"]["runs"] == 2
    report = (out / "sweep_report.md").read_text()
    assert "## Obstacle violations by the run's verdict" in report

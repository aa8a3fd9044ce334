"""CLI overrides: --prediction and --set reach the run's config (and its config.toml); a bad one is one line, exit 2."""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest
from typer.testing import CliRunner

from compare.analysis.results import load_steps
from compare.cli import app

CONFIGS = Path(__file__).resolve().parents[2] / "configs"


def test_prediction_and_set_reach_the_run(tmp_path):
    out = tmp_path / "run"
    args = ["run", str(CONFIGS / "case2.toml"), "--sensing", "geometric", "--duration", "1.0", "-m", "tpik"]
    args += ["--prediction", "estimated", "--set", "sensor.rho_m=1.0", "--set", "prediction.horizon_s=0.25"]
    args += ["--seed", "7"]
    result = CliRunner().invoke(app, [*args, "--no-plots", "-q", "--out", str(out)])
    assert result.exit_code == 0, result.output
    written = tomllib.loads((out / "config.toml").read_text())
    assert written["prediction"]["mode"] == "estimated" and written["prediction"]["horizon_s"] == 0.25
    assert written["sensor"]["rho_m"] == 1.0
    assert written["scenario"]["seed"] == 7
    assert any(c.startswith("closing_pred:") for c in load_steps(out, "tpik").columns)


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--set", "sensor.rho_m"], "--set: KEY=VALUE expected"),
        (["--set", "sensor.no_such_key=1"], "no_such_key"),
        (["--set", "sensor.rho_m=-1"], "rho_m"),
        (["--prediction", "psychic"], "prediction.mode"),
    ],
)
def test_a_bad_override_is_one_line_and_exit_2(tmp_path, extra, message):
    args = ["run", str(CONFIGS / "case2.toml"), "--duration", "0.1", *extra, "--out", str(tmp_path / "r")]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 2
    assert message in result.output and "Traceback" not in result.output
    assert not (tmp_path / "r").exists()

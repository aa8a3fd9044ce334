"""The plant benchmark and the throughput ceiling (scripts/plant_bench.py): the ceiling's arithmetic on
a sweep of known solve times, the plant row of a real randomized scenario, the script's command line."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from plant_bench import RANDOM_CONFIG, main, plant_config_of, read_sweep_solves, run_plant_bench, throughput_ceiling

from compare.config import load_config


def _sweep(root: Path, solve_us: dict[str, list[float]], dt: float = 0.01) -> Path:
    """A sweep directory with one steps table per (run, method): the given solve times per run."""
    for method, per_run in solve_us.items():
        for run, us in enumerate(per_run):
            run_dir = root / "runs" / f"{run:05d}"
            steps = run_dir / "steps"
            steps.mkdir(parents=True, exist_ok=True)
            n = 10
            table = pd.DataFrame({"t": np.arange(n) * dt, "solve_time_us": np.full(n, us)})
            table.to_parquet(steps / f"{method}.parquet")
            summary = run_dir / "summary.json"
            listed = json.loads(summary.read_text()) if summary.exists() else {"methods": {}}
            listed["methods"][method] = {}
            summary.write_text(json.dumps(listed))
    return root


def test_ceiling_is_the_period_over_the_mean_solve_plus_the_plant(tmp_path):
    sweep = _sweep(tmp_path, {"tpik": [20.0, 40.0], "mink": [300.0, 340.0]})
    c = throughput_ceiling(read_sweep_solves(sweep), plant_us=40.0)
    assert c["mean_solve_us"] == pytest.approx({"tpik": 30.0, "mink": 320.0})
    assert c["mean_solve_all_us"] == pytest.approx(175.0)
    assert c["dt_s"] == pytest.approx(0.01)
    assert c["ceiling_sim_s_per_cpu_s"] == pytest.approx(0.01 / 215e-6)
    with pytest.raises(FileNotFoundError, match="not a finished sweep"):
        read_sweep_solves(tmp_path / "nothing")


def test_plant_row_times_every_period_of_the_dynamic_plant():
    config, _ = load_config(RANDOM_CONFIG, {"scenario.sensing": "geometric"})
    row = run_plant_bench(config, steps=200)
    assert (row.name, row.case, row.samples) == ("plant", "dynamic-decoupled", 200)
    assert row.extra["dt_s"] == config.scenario.dt and row.extra["substeps"] >= 1
    assert 0 < row.median_us <= row.p95_us and row.extra["mean_us"] > 0
    assert 0 < row.extra["cpu_mean_us"] <= 2 * row.extra["mean_us"]


def test_the_script_writes_the_ceiling_and_refuses_a_directory_without_a_sweep(tmp_path, capsys):
    sweep = _sweep(tmp_path / "sweep", {"tpik": [30.0], "hqp-daqp": [150.0]})
    out = tmp_path / "plant.json"
    argv = ["--steps", "200", "--sweep", str(sweep), "--json", str(out)]
    assert main(argv) == 0
    payload = json.loads(out.read_text())
    assert set(payload) == {"versions", "command", "results", "throughput_ceiling"}
    assert payload["command"] == f"python scripts/plant_bench.py {' '.join(argv)}"
    (row,) = payload["results"]
    assert row["name"] == "plant" and {"name", "case", "median_us", "p95_us"} <= set(row)
    ceiling = payload["throughput_ceiling"]
    assert ceiling["ceiling_sim_s_per_cpu_s"] == pytest.approx(0.01 / ((90.0 + ceiling["plant_us"]) * 1e-6))
    capsys.readouterr()
    for bad in (["--sweep", str(tmp_path / "none")], ["--steps", "10"]):
        with pytest.raises(SystemExit) as exit_:
            main(["--steps", "200", *bad])
        assert exit_.value.code == 2 and capsys.readouterr().err.startswith("error: argument ")


def test_the_plant_timed_for_a_sweep_is_its_own_unless_another_is_given(tmp_path):
    sweep = _sweep(tmp_path / "sweep", {"tpik": [30.0]})
    assert plant_config_of(None, sweep) == RANDOM_CONFIG  # a sweep without its config.toml
    assert plant_config_of(None, None) == RANDOM_CONFIG
    text = RANDOM_CONFIG.read_text().replace('simulation = "dynamic"', 'simulation = "kinematic"', 1)
    assert 'simulation = "kinematic"' in text
    (sweep / "config.toml").write_text(text)
    assert plant_config_of(None, sweep) == sweep / "config.toml"
    assert plant_config_of(RANDOM_CONFIG, sweep) == RANDOM_CONFIG
    out = tmp_path / "plant.json"
    argv = ["--steps", "200", "--sweep", str(sweep), "--json", str(out)]
    assert main(argv) == 0
    payload = json.loads(out.read_text())
    assert payload["results"][0]["case"].startswith("kinematic-")  # the sweep's plant, not the default's
    assert payload["throughput_ceiling"]["plant_config"] == str(sweep / "config.toml")
    assert main([*argv, "--family", str(RANDOM_CONFIG)]) == 0
    payload = json.loads(out.read_text())
    assert payload["results"][0]["case"] == "dynamic-decoupled"
    assert payload["throughput_ceiling"]["plant_config"] == str(RANDOM_CONFIG)

"""docs/extending.md, done: a new set-based task, and a new metric, in one file each, from TOML.

``docs/examples/elbow_height.py`` defines and registers ``elbow_height``; the scenario
``docs/examples/elbow_height.toml`` imports it (``[extensions]``) and runs TPIK, HQP and mink
on it. The task's σ is recomputed here from the recorded joint positions with the model's
forward kinematics (pinocchio), independently of the task class.

``docs/examples/ee_path_length.py`` registers the metric ``ee_path_length_m``; a sweep whose
config imports it has it in every run's summary (checked against the forward kinematics of the
recorded joints), in ``sweep_runs.csv``, ``sweep_summary.json``, the run table and the sweep report.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from rich.console import Console
from typer.testing import CliRunner

import compare.config
import robots
from compare.analysis.metrics import registered_metrics, unregister_metric
from compare.analysis.report import summary_table
from compare.analysis.results import flatten_method, load_summary, sweep_run_dir
from compare.campaign.sweep import run_sweep
from compare.cli import app
from compare.config import import_extensions, load_config
from compare.run import run_scenario
from tests.test_jacobians import assert_jacobian_matches_finite_differences
from tpik import TaskDefinitionError, build_tasks

EXAMPLES = Path(__file__).resolve().parents[1] / "docs" / "examples"
CONFIGS = Path(__file__).resolve().parents[1] / "configs"
TOML = EXAMPLES / "elbow_height.toml"
METRIC = "ee_path_length_m"
METHODS = ("tpik", "hqp-daqp", "mink")
MIN_HEIGHT_M = 0.6  # as in the TOML
START_Q = [4.71, 2.24, 0.0, 0.75, 4.62, 4.48, 4.88]  # home with joint 2 lowered: elbow at 0.53 m


def _run(out: Path, *extra: str) -> dict:
    result = CliRunner().invoke(app, ["run", str(TOML), "--out", str(out), "-q", "--no-plots", *extra])
    assert result.exit_code == 0, result.output
    return json.loads((out / "summary.json").read_text())


def _elbow_heights(out: Path, method: str, robot: robots.Robot) -> tuple[np.ndarray, pd.DataFrame]:
    steps = pd.read_parquet(out / "steps" / f"{method}.parquet")
    q = steps[[f"q_{i}" for i in range(1, robot.nq + 1)]].to_numpy()
    return np.array([robot.frame_position(qi, "link_4")[2] for qi in q]), steps


@pytest.fixture(scope="module")
def jaco_model() -> robots.Robot:
    return robots.load("jaco2")


@pytest.fixture(scope="module")
def held(tmp_path_factory) -> tuple[Path, dict]:
    out = tmp_path_factory.mktemp("elbow") / "held"
    return out, _run(out)


@pytest.mark.slow
@pytest.mark.parametrize("method", METHODS)
def test_the_new_task_holds_the_elbow_under_every_method(held, method, jaco_model):
    out, summary = held
    m = summary["methods"][method]
    group = m["groups"]["elbow_height"]
    assert group["tasks"] == 1
    assert {"name": "elbow_height", "group": "elbow_height"}.items() <= m["set_tasks"][-1].items()
    assert m["set_tasks"][-1]["safety_lower"] == MIN_HEIGHT_M
    z, steps = _elbow_heights(out, method, jaco_model)
    # The margin in summary.json is the independent forward kinematics' lowest elbow height.
    assert group["safety_margin_min"] == pytest.approx(z.min() - MIN_HEIGHT_M, abs=1e-9)
    assert group["safety_margin_min"] > -1e-3 and group["violations"] == 0
    # The waypoints pull the elbow down to its threshold (the task acts), and both are reached.
    assert steps["active:elbow_height"].any()
    assert z.min() < MIN_HEIGHT_M + 0.01
    assert m["waypoints_reached"] == 2
    assert m["joint_limits"] is not None and m["walls"] is None  # the docs/design.md §7 keys stay


@pytest.mark.slow
@pytest.mark.parametrize("method", METHODS)
def test_a_start_below_the_threshold_is_counted_as_its_violation(tmp_path, method, jaco_model):
    # The same scenario, started with the elbow 7 cm below its threshold.
    config, text = load_config(TOML, {"scenario.duration_s": 3.0, "scenario.start_q": START_Q})
    config = config.model_copy(update={"methods": config.methods.model_copy(update={"names": [method]})})
    out = tmp_path / method
    summary = run_scenario(config, out, config_text=text, progress=False, make_plots=False)
    m = summary["methods"][method]
    group = m["groups"]["elbow_height"]
    z, _ = _elbow_heights(out, method, jaco_model)
    z0 = jaco_model.frame_position(np.array(START_Q), "link_4")[2]
    assert z0 < MIN_HEIGHT_M - 0.05
    assert group["violations"] >= 1 and group["violation_time_s"] > 0.0
    assert group["safety_margin_min"] == pytest.approx(z.min() - MIN_HEIGHT_M, abs=1e-9)
    assert group["safety_margin_min"] == pytest.approx(z0 - MIN_HEIGHT_M, abs=2e-3)  # worst at the start
    assert z[-1] > z0 + 0.05  # brought back up toward the threshold
    # A sweep row and the run table carry the group too.
    row = flatten_method(m)
    assert row["elbow_height_violations"] == group["violations"] and row["elbow_height_present"]
    console = Console(width=250, record=True)
    console.print(summary_table(summary))
    assert "elbow_height margin" in console.export_text()


def test_the_example_task_jacobian_matches_finite_differences(jaco_model):
    import_extensions([str(EXAMPLES / "elbow_height.py")])
    (task,) = build_tasks({"type": "elbow_height", "min_height_m": 0.5}, jaco_model, "levels[0].tasks[0]")
    assert task.group == "elbow_height"
    assert_jacobian_matches_finite_differences(task, jaco_model)


def test_the_example_task_errors_name_the_key(jaco_model):
    import_extensions([str(EXAMPLES / "elbow_height.py")])
    with pytest.raises(TaskDefinitionError, match=r"^levels\[1\]\.tasks\[0\]\.min_height_m: must be a finite number"):
        build_tasks({"type": "elbow_height", "min_height_m": "low"}, jaco_model, "levels[1].tasks[0]")
    with pytest.raises(TaskDefinitionError, match=r"^levels\[1\]\.tasks\[0\]\.frame: unknown frame 'elbow'"):
        build_tasks({"type": "elbow_height", "frame": "elbow"}, jaco_model, "levels[1].tasks[0]")


def test_the_page_shows_the_example_files_as_they_are():
    page = (EXAMPLES.parent / "extending.md").read_text(encoding="utf-8")
    for name, fence in (("elbow_height.py", "python"), ("elbow_height.toml", "toml"), ("ee_path_length.py", "python")):
        source = (EXAMPLES / name).read_text(encoding="utf-8").rstrip()
        assert f"```{fence}\n{source}\n```" in page, f"docs/extending.md does not show {name} as it is"


@pytest.fixture
def path_metric(monkeypatch: pytest.MonkeyPatch):
    """The example metric's module imported as an extension, and forgotten afterwards (the registry is global)."""
    monkeypatch.setattr(compare.config, "_EXTENSIONS", {})
    yield str(EXAMPLES / "ee_path_length.py")
    unregister_metric(METRIC)


def _fk_path_length(steps: pd.DataFrame, robot: robots.Robot) -> float:
    q = steps[[f"q_{i}" for i in range(1, robot.nq + 1)]].to_numpy()
    p = np.array([robot.frame_position(qi, robot.ee_frame) for qi in q])
    return float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum())


@pytest.mark.slow
def test_a_new_metric_reaches_the_summary_the_sweep_and_the_reports(tmp_path, path_metric, jaco_model):
    overrides = {
        "scenario.duration_s": 3.0,
        "scenario.simulation": "kinematic",
        "scenario.sensing": "geometric",
        "extensions.modules": [path_metric],
        "methods.names": ["tpik", "hqp-daqp"],
    }
    config, text = load_config(CONFIGS / "random.toml", overrides)
    sweep = run_sweep(config, text, tmp_path, n=2, workers=1, progress=False)
    assert METRIC in {m.name for m in registered_metrics()}  # imported by the sweep, from [extensions]
    lengths: dict[str, list[float]] = {"tpik": [], "hqp-daqp": []}
    for k in range(2):
        run_dir = sweep_run_dir(tmp_path, k)
        summary = load_summary(run_dir)
        for method, values in lengths.items():
            steps = pd.read_parquet(run_dir / summary["methods"][method]["steps_file"])
            value = summary["methods"][method][METRIC]
            assert value == pytest.approx(_fk_path_length(steps, jaco_model), rel=1e-9)
            assert value > 0.05  # the arm moved toward its waypoints
            values.append(value)
    console = Console(width=250, record=True)
    console.print(summary_table(summary))
    assert "EE path [m]" in console.export_text()
    rows = pd.read_csv(tmp_path / "sweep_runs.csv")
    assert sorted(rows[METRIC]) == pytest.approx(sorted(lengths["tpik"] + lengths["hqp-daqp"]))
    for method, values in lengths.items():
        assert sweep["methods"][method][METRIC] == pytest.approx({"median": np.median(values), "max": max(values)})
    report = (tmp_path / "sweep_report.md").read_text(encoding="utf-8")
    assert "## Other metrics per method" in report and "EE path [m], median of runs" in report

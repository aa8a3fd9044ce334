"""docs/extending.md, done: a new set-based task in one file plus one registration, from TOML.

``docs/examples/elbow_height.py`` defines and registers ``elbow_height``; the scenario
``docs/examples/elbow_height.toml`` imports it (``[extensions]``) and runs TPIK, HQP and mink
on it. The task's σ is recomputed here from the recorded joint positions with the model's
forward kinematics (pinocchio), independently of the task class.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

import robots
from compare.analysis.report import render_report
from compare.analysis.results import flatten_method
from compare.cli import app
from compare.config import import_extensions, load_config
from compare.run import run_scenario
from tests.test_jacobians import assert_jacobian_matches_finite_differences
from tpik import TaskDefinitionError, build_tasks

EXAMPLES = Path(__file__).resolve().parents[1] / "docs" / "examples"
TOML = EXAMPLES / "elbow_height.toml"
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
    assert m["joint_limits"] is not None and m["walls"] is None  # the DESIGN §7 keys stay


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
    # A sweep row and the run report carry the group too.
    row = flatten_method(m)
    assert row["elbow_height_violations"] == group["violations"] and row["elbow_height_present"]
    assert "elbow_height margin" in render_report(out).read_text()


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
    for name, fence in (("elbow_height.py", "python"), ("elbow_height.toml", "toml")):
        source = (EXAMPLES / name).read_text(encoding="utf-8").rstrip()
        assert f"```{fence}\n{source}\n```" in page, f"docs/extending.md does not show {name} as it is"

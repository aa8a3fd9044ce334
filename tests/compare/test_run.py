"""End to end: the paper's case studies in short form, numbers asserted from summary.json.

Short form = ``scenario.time_scale`` < 1: the same events (person in, person out) earlier.
Tolerances: joint limits and walls within their safety thresholds up to 2 mrad / 2 mm (the
discrete-time step and the servo tracking lag of the dynamic simulation); obstacle distances
never below the physical threshold.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from compare.cli import app
from tests.compare.analysis.test_metrics import REQUIRED_KEYS
from tests.compare.analysis.test_run_report import assert_table_is_the_summary

CONFIGS = Path(__file__).resolve().parents[2] / "configs"
SAFETY_TOL = {"joint_limits": 2e-3, "walls": 2e-3}
SAFE_METHODS = ("tpik", "hqp-daqp")
CASE1_SCALE = 0.4
# configs/case1.toml, scaled: the person starts stepping in at 35 s, is in by 37 s, starts
# leaving at 55 s and is back in place at 57 s.
CASE1_APPROACH_S, CASE1_IN_S, CASE1_LEAVE_S, CASE1_GONE_S = (CASE1_SCALE * t for t in (35.0, 37.0, 55.0, 57.0))
CASE1_P1, CASE1_P2 = np.array([-0.5, 0.4, 0.7]), np.array([0.5, 0.4, 0.7])


def _run(tmp_path: Path, config: str, *extra: str) -> dict:
    out = tmp_path / Path(config).stem
    result = CliRunner().invoke(app, ["run", str(CONFIGS / config), "--out", str(out), "-q", *extra])
    assert result.exit_code == 0, result.output
    return json.loads((out / "summary.json").read_text())


@pytest.fixture(scope="module")
def case1_dir(tmp_path_factory) -> Path:
    tmp = tmp_path_factory.mktemp("case1")
    methods = ["-m", "tpik", "-m", "hqp-daqp", "-m", "mink"]
    _run(tmp, "case1.toml", "--time-scale", str(CASE1_SCALE), "--sensing", "geometric", *methods)
    return tmp / "case1"


@pytest.fixture(scope="module")
def case1(case1_dir) -> dict:
    return json.loads((case1_dir / "summary.json").read_text())


@pytest.fixture(scope="module")
def case2(tmp_path_factory) -> dict:
    tmp = tmp_path_factory.mktemp("case2")
    return _run(
        tmp, "case2.toml", "--time-scale", "0.5", "--sensing", "geometric", "-m", "tpik", "-m", "hqp-daqp", "-m", "mink"
    )


@pytest.mark.slow
@pytest.mark.parametrize("method", SAFE_METHODS)
def test_case1_keeps_joint_limits_and_physical_distance(case1, method):
    m = case1["methods"][method]
    assert m["joint_limits"]["safety_margin_min"] > -SAFETY_TOL["joint_limits"]
    assert m["obstacles"]["physical_margin_min"] > 0.0
    _no_failed_step(m)


def _no_failed_step(m: dict) -> None:
    """No failed step and no fallback: in simulation a late solve (a deadline miss, how many
    depends on the machine's load) is only reported."""
    assert m["failures"] == m["fallbacks"] == 0
    assert 0 <= m["deadline_misses"] <= m["steps"]


def _obstacle_activity(steps: pd.DataFrame) -> np.ndarray:
    columns = [c for c in steps.columns if c.startswith("active:obstacle_")]
    assert len(columns) == 3
    return steps[columns].to_numpy(dtype=bool).any(axis=1)


@pytest.mark.slow
@pytest.mark.parametrize("method", SAFE_METHODS)
def test_case1_obstacle_tasks_are_active_exactly_while_the_person_is_in(case1_dir, method):
    steps = pd.read_parquet(case1_dir / "steps" / f"{method}.parquet")
    t, active = steps["t"].to_numpy(), _obstacle_activity(steps)
    assert not active[t < CASE1_APPROACH_S].any()  # standing near the arm, outside the activation band
    assert active[(t >= CASE1_IN_S) & (t <= CASE1_LEAVE_S)].any()
    assert not active[t > CASE1_GONE_S + 0.5].any()


@pytest.mark.slow
@pytest.mark.parametrize("method", SAFE_METHODS)
def test_case1_arm_gives_way_while_the_person_is_in_and_resumes_after(case1_dir, case1, method):
    """The paper's case 1: the arm stops short of the person (held off its path) and resumes."""
    steps = pd.read_parquet(case1_dir / "steps" / f"{method}.parquet")
    t, active = steps["t"].to_numpy(), _obstacle_activity(steps)
    ee = steps[["ee_x", "ee_y", "ee_z"]].to_numpy()
    error = steps["ee_error_m"].to_numpy()
    tolerance = case1["methods"][method]["waypoint_tolerance_m"]
    # Distance of the EE from the straight p1–p2 path it follows when nobody is in the way.
    axis = (CASE1_P2 - CASE1_P1) / np.linalg.norm(CASE1_P2 - CASE1_P1)
    rel = ee - CASE1_P1
    off_path = np.linalg.norm(rel - np.outer(rel @ axis, axis), axis=1)
    cycling = (t >= t[np.argmax(error < tolerance)]) & (t < CASE1_APPROACH_S)  # p1 reached, nobody near
    assert off_path[active].max() > max(2.0 * off_path[cycling].max(), 0.08)
    # Once the person has left, a waypoint is reached within 4 s and the EE goes on cycling.
    reached = np.flatnonzero((t > CASE1_LEAVE_S) & (error < tolerance))
    assert reached.size and t[reached[0]] < CASE1_GONE_S + 4.0
    waypoint = steps["waypoint"].to_numpy()
    assert np.unique(waypoint[t > t[reached[0]]]).size == 2


@pytest.mark.slow
@pytest.mark.parametrize("method", SAFE_METHODS)
def test_case1_reaches_waypoints_while_person_is_away(case1, method):
    m = case1["methods"][method]
    # Before the person steps in (t = 35 s × 0.4 = 14 s) p1 then p2 are reached.
    assert m["waypoints_reached"] >= 2
    assert m["time_to_waypoint_s"][0] is not None and m["time_to_waypoint_s"][0] < 14.0


@pytest.mark.slow
@pytest.mark.parametrize("method", SAFE_METHODS)
def test_case2_keeps_walls_joint_limits_and_physical_distance(case2, method):
    m = case2["methods"][method]
    assert m["walls"]["safety_margin_min"] > -SAFETY_TOL["walls"]
    assert m["joint_limits"]["safety_margin_min"] > -SAFETY_TOL["joint_limits"]
    assert m["obstacles"]["physical_margin_min"] > 0.0
    # The person pushed the arm: some obstacle task was active.
    assert m["activation_toggles_per_s"] > 0.0


@pytest.mark.slow
def test_summary_has_design_keys_and_every_method(case1):
    assert set(case1["methods"]) == {"tpik", "hqp-daqp", "mink"}
    assert {"scenario", "seed", "sim_time_s", "versions", "methods"} <= set(case1)
    for m in case1["methods"].values():
        assert REQUIRED_KEYS <= set(m)
        assert m["walls"] is None  # case 1 has no walls
        assert set(m["solve_time_us"]) == {"median", "p95", "p99", "max"}


@pytest.mark.slow
@pytest.mark.rendering
def test_case1_short_with_depth_sensing(tmp_path):
    summary = _run(tmp_path, "case1.toml", "--time-scale", "0.2", "--duration", "70", "-m", "tpik")
    m = summary["methods"]["tpik"]
    assert m["sensing"] == "depth"
    assert m["joint_limits"]["safety_margin_min"] > -SAFETY_TOL["joint_limits"]
    assert m["obstacles"]["physical_margin_min"] > 0.0
    _no_failed_step(m)


# ------------------------------------------------------------------ one results directory, several runs

PAIR = ["--duration", "0.3", "--sensing", "geometric", "--no-plots", "-q"]


def _invoke(config: str, out: Path, *extra: str):
    return CliRunner().invoke(app, ["run", str(CONFIGS / config), "--out", str(out), *PAIR, *extra])


def test_one_method_then_another_into_one_directory_keeps_both(tmp_path):
    """The first command pair of a run added to: the second run adds its method, the first stays as it was.

    Each run writes report.md: the table of every method in summary.json, and no claim checked on
    a run shorter than the person's visit.
    """
    out = tmp_path / "R"
    first = _invoke("case1.toml", out, "-m", "tpik")
    assert first.exit_code == 0, first.output
    assert f"report:  {out}/report.md" in first.output
    assert_table_is_the_summary(out)
    tpik_table = out / "steps" / "tpik.parquet"
    before = (tpik_table.read_bytes(), json.loads((out / "summary.json").read_text())["methods"]["tpik"])
    second = _invoke("case1.toml", out, "-m", "hqp-daqp")
    assert second.exit_code == 0, second.output
    summary = json.loads((out / "summary.json").read_text())
    assert set(summary["methods"]) == {"tpik", "hqp-daqp"}
    assert (tpik_table.read_bytes(), summary["methods"]["tpik"]) == before
    assert summary["methods"]["hqp-daqp"]["steps_file"] == "steps/hqp-daqp.parquet"
    assert (out / "steps" / "hqp-daqp.parquet").is_file()
    assert_table_is_the_summary(out)
    report = (out / "report.md").read_text()
    assert "Not checked for tpik, hqp-daqp: the run covers 0.3 s, the claims read it to 59 s" in report


def test_a_run_that_would_replace_or_mix_results_is_one_line_and_exit_2(tmp_path):
    out = tmp_path / "R"
    assert _invoke("case1.toml", out, "-m", "tpik").exit_code == 0
    kept = (out / "summary.json").read_bytes()
    again = _invoke("case1.toml", out, "-m", "tpik")
    assert again.exit_code == 2
    assert (
        again.output
        == f"error: {out} already holds finished results of tpik; use --overwrite to replace them, or another --out\n"
    )
    other = _invoke("case2.toml", out, "-m", "mink")
    assert other.exit_code == 2 and other.output.count("\n") == 1
    assert 'another configuration (scenario.kind "case1" → "case2"' in other.output
    longer = _invoke("case1.toml", out, "-m", "mink", "--duration", "0.4")
    assert longer.exit_code == 2 and "(scenario.duration_s 0.3 → 0.4)" in longer.output
    assert (out / "summary.json").read_bytes() == kept  # refused before anything was written
    replaced = _invoke("case1.toml", out, "-m", "mink", "--duration", "0.4", "--overwrite")
    assert replaced.exit_code == 0, replaced.output
    summary = json.loads((out / "summary.json").read_text())
    assert set(summary["methods"]) == {"mink"} and summary["sim_time_s"] == pytest.approx(0.4)
    assert not (out / "steps" / "tpik.parquet").exists()


def test_run_help_says_what_happens_to_a_directory_with_results():
    result = CliRunner().invoke(app, ["run", "--help"], terminal_width=200)
    assert result.exit_code == 0
    text = " ".join(result.output.split())
    assert "gets these methods added" in text and "--overwrite" in text and "refused (exit 2)" in text


@pytest.mark.slow
@pytest.mark.rendering
def test_case1_with_two_cameras_logs_what_each_reading_is(tmp_path):
    import numpy as np

    from compare.analysis.results import load_steps

    summary = _run(tmp_path, "case1_two_cameras.toml", "--time-scale", "0.2", "-m", "tpik")
    m = summary["methods"]["tpik"]
    assert m["sensing"] == "depth"
    assert m["obstacles"]["physical_margin_min"] > 0.0
    _no_failed_step(m)
    steps = load_steps(tmp_path / "case1_two_cameras", "tpik")
    seen = set()
    for cp in ("link_4", "link_6", "link_7"):
        measured = np.isfinite(steps[f"dist_meas:{cp}"].to_numpy(dtype=float))
        cameras = steps[f"camera:{cp}"].astype(str).to_numpy()
        # A reading in range names its camera; no reading, no camera and never "occluded".
        assert set(cameras[measured]) <= {"depth_camera", "depth_camera_2"} and "" not in set(cameras[measured])
        assert set(cameras[~measured]) <= {""}
        assert not steps[f"occluded:{cp}"].to_numpy(dtype=bool)[~measured].any()
        seen |= set(cameras[measured])
    assert measured.any() and seen  # the person stepped in and was seen

"""``tpik-compare tune``: one sweep per grid point of a method's settings, ranked by one stated rule."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from typer.testing import CliRunner

from compare.analysis.results import SWEEP_RUNS_FILE, SWEEP_SUMMARY_FILE
from compare.campaign.tuning import (
    TUNING_FILE,
    TUNING_REPORT,
    GridError,
    grid_points,
    parse_grid,
    point_name,
    point_overrides,
    write_tuning,
)
from compare.cli import app

CONFIGS = Path(__file__).resolve().parents[3] / "configs"
GRID = ["level_cost_ratio=3,10,30", "posture_cost=1e-2,0.1"]


def test_the_mink_posture_grid_has_six_points_with_typed_values():
    points = grid_points(parse_grid(GRID))
    assert len(points) == 6
    assert points[0] == {"level_cost_ratio": 3, "posture_cost": 0.01} and points[-1]["level_cost_ratio"] == 30
    assert {p["posture_cost"] for p in points} == {0.01, 0.1}
    assert point_name(points[1]) == "level_cost_ratio-3_posture_cost-0.1"
    assert point_overrides("mink-posture", points[1]) == {
        "methods.names": ["mink-posture"],
        "methods.settings.mink-posture.level_cost_ratio": 3,
        "methods.settings.mink-posture.posture_cost": 0.1,
    }


@pytest.mark.parametrize("bad", [["level_cost_ratio"], ["level_cost_ratio="], ["a=1", "a=2"], []])
def test_a_malformed_grid_is_refused(bad):
    with pytest.raises(GridError, match="--grid"):
        parse_grid(bad)


def _summary(runs: int, violations: int, below_s: float, failed: int, ee: float) -> dict:
    share = {"count": violations, "runs": runs, "rate": violations / runs, "ci95": [0.0, 1.0]}
    return {
        "methods": {
            "mink-posture": {
                "runs": runs,
                "share_runs_limit_or_wall_violation": share,
                "share_runs_obstacle_violation": {"count": 0, "runs": runs, "rate": 0.0, "ci95": [0.0, 1.0]},
                "status_steps": {"ok": 100, "degraded": 3, "failed": failed},
                "time_below_physical_s": below_s,
                "ee_error_final_m": {"median": ee},
                "solve_time_us": {"median_of_medians": 180.0},
            }
        }
    }


def test_points_tracking_the_ee_are_ranked_by_violations_time_below_failed_steps_then_ee_error(tmp_path):
    points = grid_points(parse_grid(GRID))
    figures = {  # point index → (violations, time below [s], failed steps, EE error [m])
        0: (1, 0.0, 0, 0.010),  # a violation: last of the points that track the EE
        1: (0, 2.0, 0, 0.010),
        2: (0, 1.0, 5, 0.015),
        3: (0, 1.0, 5, 0.012),  # ties 2 on everything but the EE error: ahead of it
        4: (0, 1.0, 0, 0.018),  # the choice: tracks the EE, no violation, least time below, no failed step
        5: (0, 0.0, 0, 0.500),  # the safest figures, but it stopped following the target (> 2 × 0.010 m)
    }
    for i, (violations, below, failed, ee) in figures.items():
        d = tmp_path / point_name(points[i])
        d.mkdir()
        (d / SWEEP_SUMMARY_FILE).write_text(json.dumps(_summary(10, violations, below, failed, ee)))
    report = write_tuning(tmp_path, "mink-posture", points, "tpik-compare tune ...")
    table = json.loads((tmp_path / TUNING_FILE).read_text())
    assert [e["point"] for e in table["points"]] == [points[i] for i in (4, 3, 2, 1, 0, 5)]
    assert table["choice"] == points[4] and table["command"] == "tpik-compare tune ..."
    text = report.read_text()
    assert report.name == TUNING_REPORT and "6 of 6 points" in text and "level_cost_ratio = 30" in text


def test_a_point_that_reaches_few_waypoints_does_not_track_the_ee(tmp_path):
    points = grid_points(parse_grid(["posture_cost=0.01,0.1"]))
    for point, violations, reached in ((points[0], 0, "0,1,0"), (points[1], 1, "4,3,5")):
        d = tmp_path / point_name(point)
        d.mkdir()
        (d / SWEEP_SUMMARY_FILE).write_text(json.dumps(_summary(3, violations, 0.0, 0, 0.01)))
        rows = "".join(f"{k},mink-posture,{w}\n" for k, w in enumerate(reached.split(",")))
        (d / SWEEP_RUNS_FILE).write_text("run,method,waypoints_reached\n" + rows)
    write_tuning(tmp_path, "mink-posture", points, "c")
    table = json.loads((tmp_path / TUNING_FILE).read_text())
    # 1/3 waypoint per run against 4: held near its start, it is ranked after a point with a violation
    assert table["choice"] == points[1]
    assert [e["waypoints_reached_mean"] for e in table["points"]] == [4.0, pytest.approx(1 / 3)]


def test_a_point_not_finished_is_left_out(tmp_path):
    points = grid_points(parse_grid(["level_cost_ratio=3,10"]))
    d = tmp_path / point_name(points[1])
    d.mkdir()
    (d / SWEEP_SUMMARY_FILE).write_text(json.dumps(_summary(10, 0, 0.0, 0, 0.01)))
    (tmp_path / point_name(points[0])).mkdir()  # begun, no summary yet
    report = write_tuning(tmp_path, "mink-posture", points, "c")
    assert json.loads((tmp_path / TUNING_FILE).read_text())["choice"] == points[1]
    assert "1 of 2 points" in report.read_text()


@pytest.mark.slow
def test_the_cli_checks_every_point_before_running_and_runs_a_small_grid(tmp_path):
    base = ["tune", str(CONFIGS / "random.toml"), "-m", "mink-posture", "--n", "1", "--workers", "1"]
    bad = CliRunner().invoke(app, [*base, "--grid", "posture_cost=0.01,-1", "--out", str(tmp_path / "bad")])
    assert bad.exit_code == 2 and "methods.settings.mink-posture" in bad.output
    assert not (tmp_path / "bad").exists()  # refused before the first run
    out = tmp_path / "grid"
    args = [*base, "--grid", "level_cost_ratio=3,30", "--duration", "0.3", "--seed", "0", "--out", str(out)]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 0, result.output
    table = json.loads((out / TUNING_FILE).read_text())
    assert len(table["points"]) == 2 and all(e["runs"] == 1 for e in table["points"])
    manifest = json.loads((out / "level_cost_ratio-30" / "sweep_manifest.json").read_text())
    assert manifest["method_settings"] == {"mink-posture": {"level_cost_ratio": 30}}

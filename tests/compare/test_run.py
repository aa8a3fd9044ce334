"""End to end: the paper's case studies in short form, numbers asserted from summary.json.

Short form = ``scenario.time_scale`` < 1: the same events (person in, person out) earlier.
Tolerances: joint limits and walls within their safety thresholds up to 2 mrad / 2 mm (the
discrete-time step and the servo tracking lag of the dynamic simulation); obstacle distances
never below the physical threshold.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from typer.testing import CliRunner

from compare.cli import app
from tests.compare.analysis.test_metrics import REQUIRED_KEYS

CONFIGS = Path(__file__).resolve().parents[2] / "configs"
SAFETY_TOL = {"joint_limits": 2e-3, "walls": 2e-3}
SAFE_METHODS = ("tpik", "hqp-daqp")


def _run(tmp_path: Path, config: str, *extra: str) -> dict:
    out = tmp_path / Path(config).stem
    result = CliRunner().invoke(app, ["run", str(CONFIGS / config), "--out", str(out), "-q", *extra])
    assert result.exit_code == 0, result.output
    return json.loads((out / "summary.json").read_text())


@pytest.fixture(scope="module")
def case1(tmp_path_factory) -> dict:
    tmp = tmp_path_factory.mktemp("case1")
    return _run(
        tmp, "case1.toml", "--time-scale", "0.4", "--sensing", "geometric", "-m", "tpik", "-m", "hqp-daqp", "-m", "mink"
    )


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
    assert m["failures"] == 0 and m["fallbacks"] == 0
    # The person steps in: the obstacle tasks must have been active at some point.
    assert min(d for d in m["min_obstacle_distance_m"] if d is not None) < 0.5


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
    assert m["failures"] == 0


@pytest.mark.slow
@pytest.mark.rendering
def test_case1_with_two_cameras_logs_what_each_reading_is(tmp_path):
    import numpy as np

    from compare.analysis.results import load_steps

    summary = _run(tmp_path, "case1_two_cameras.toml", "--time-scale", "0.2", "-m", "tpik")
    m = summary["methods"]["tpik"]
    assert m["sensing"] == "depth"
    assert m["obstacles"]["physical_margin_min"] > 0.0 and m["failures"] == 0
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

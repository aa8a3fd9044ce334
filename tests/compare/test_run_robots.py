"""End to end on the Panda and the UR5: the paper's case 2 in short form, and the elbow swivel.

Numbers asserted from summary.json and the per-step tables (tolerances as ``test_run.py``).
"""

from __future__ import annotations

import json
from pathlib import Path

import pandas as pd
import pytest
from typer.testing import CliRunner

from compare.cli import app
from tests.compare.test_run import CONFIGS, SAFETY_TOL


def _run(tmp_path: Path, config: str, *extra: str) -> tuple[dict, Path]:
    out = tmp_path / Path(config).stem
    result = CliRunner().invoke(app, ["run", str(CONFIGS / config), "--out", str(out), "-q", "--no-plots", *extra])
    assert result.exit_code == 0, result.output
    return json.loads((out / "summary.json").read_text()), out


@pytest.mark.slow
@pytest.mark.rendering
@pytest.mark.parametrize(
    ("config", "robot", "cps"),
    [
        ("panda_case2.toml", "panda", ["panda_link4", "panda_link6", "panda_link7"]),
        ("ur5_case2.toml", "ur5", ["forearm_link", "wrist_2_link", "wrist_3_link"]),
    ],
)
def test_case2_short_with_depth_sensing_on_other_arms(tmp_path, config, robot, cps):
    summary, _ = _run(tmp_path, config, "--time-scale", "0.25", "-m", "tpik", "-m", "hqp-daqp")
    for m in summary["methods"].values():
        assert m["robot"] == robot and m["control_points"] == cps and m["sensing"] == "depth"
        assert m["walls"]["safety_margin_min"] > -SAFETY_TOL["walls"]
        assert m["joint_limits"]["safety_margin_min"] > -SAFETY_TOL["joint_limits"]
        assert m["obstacles"]["physical_margin_min"] > 0.0
        # no failed step but a late one (the solver time limit: a step over it is not used)
        assert m["failures"] <= m["deadline_misses"] and m["unsafe_commands"] == 0
        assert min(m["min_obstacle_distance_m"]) < 0.5  # the hand came to the arm


@pytest.mark.slow
def test_the_7_joint_panda_swings_its_elbow_and_keeps_the_pose_the_ur5_cannot(tmp_path):
    pose_kept = {}
    for config in ("panda_elbow.toml", "ur5_elbow.toml"):
        summary, out = _run(tmp_path, config, "-m", "hqp-daqp")
        m = summary["methods"]["hqp-daqp"]
        assert m["obstacles"]["physical_margin_min"] > 0.2  # the elbow kept away from the hand
        steps = pd.read_parquet(out / "steps" / "hqp-daqp.parquet")
        active = [c for c in steps.columns if c.startswith("active:obstacle_")]
        assert steps[active[0]].sum() * m["dt"] > 5.0  # the elbow task was active for seconds
        pose_kept[m["robot"]] = float(steps["ee_error_m"].max())
    assert pose_kept["panda"] < 1e-3  # self-motion: the pose (6) and the elbow (1) on 7 joints
    assert pose_kept["ur5"] > 0.1  # none on 6 joints: the EE gives way to the elbow task

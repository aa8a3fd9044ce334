"""The public registry: what is installed, registering an arm, and loading problems as one-line errors."""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import numpy as np
import pytest

import robots
from robots import NotInstalled, RobotSpec, UnknownRobot

DOCS = Path(__file__).resolve().parents[2] / "docs" / "robots.md"


@pytest.fixture
def scratch_names():
    """Names registered by a test, removed afterwards (the registry is process-wide)."""
    names: list[str] = []
    yield names
    for name in names:
        robots.unregister(name)


def test_shipped_robots_are_installed():
    assert robots.available_robots() == ["jaco2", "panda", "ur5"]
    assert robots.load("franka_panda") is robots.load("panda")  # alias, parsed once


def test_unknown_robot_names_what_exists():
    with pytest.raises(UnknownRobot, match="unknown robot 'ur10'; available: jaco2, panda, ur5"):
        robots.load("ur10")


def test_a_name_is_registered_once(scratch_names):
    spec = robots.spec_of("ur5")
    with pytest.raises(robots.InvalidSpec, match="'ur5' is already registered"):
        robots.register("ur5", spec)
    robots.register("ur5_copy", spec)
    scratch_names.append("ur5_copy")
    assert robots.load("ur5_copy").nq == 6 and robots.load("ur5_copy") is not robots.load("ur5")


def test_missing_mesh_package_makes_a_robot_unavailable_with_the_reason(tmp_path, scratch_names):
    urdf = robots.spec_of("ur5").description.read_text(encoding="utf-8")
    path = tmp_path / "ur5_elsewhere.urdf"
    path.write_text(urdf.replace("package://example-robot-data/", "package://no-such-package/"), encoding="utf-8")
    robots.register("ur5_elsewhere", RobotSpec(path, "tool0", ("wrist_3_link",), home=(0.0,) * 6))
    scratch_names.append("ur5_elsewhere")
    assert "ur5_elsewhere" in robots.registered_robots() and "ur5_elsewhere" not in robots.available_robots()
    with pytest.raises(NotInstalled, match="package 'no-such-package' not found for package://no-such-package/"):
        robots.load("ur5_elsewhere")


def test_package_dirs_of_the_spec_are_searched(tmp_path, scratch_names):
    # The same meshes under a directory of the user's: found through the spec's package_dirs.
    source = robots.spec_of("ur5").description
    meshes = tmp_path / "mine" / "robots" / "ur_description" / "meshes" / "ur5" / "collision"
    meshes.mkdir(parents=True)
    from robots.description import package_search_path, resolve_package_uri

    installed = resolve_package_uri(
        "package://example-robot-data/robots/ur_description/meshes/ur5/collision/base.stl", package_search_path()
    ).parent
    for stl in installed.glob("*.stl"):
        shutil.copy(stl, meshes / stl.name)
    path = tmp_path / "ur5_mine.urdf"
    path.write_text(source.read_text(encoding="utf-8").replace("package://example-robot-data/", "package://mine/"))
    robots.register("ur5_mine", RobotSpec(path, "tool0", ("wrist_3_link",), home=(0.0,) * 6, package_dirs=(tmp_path,)))
    scratch_names.append("ur5_mine")
    mine = robots.load("ur5_mine")
    assert all(Path(m.file).is_relative_to(tmp_path) for m in mine.mujoco_spec().meshes)
    np.testing.assert_allclose(
        robots.load("ur5_mine").frame_position(np.zeros(6), "tool0"),
        robots.load("ur5").frame_position(np.zeros(6), "tool0"),
    )


def _docs_snippet() -> str:
    text = DOCS.read_text(encoding="utf-8")
    section = text.split("## Adding a robot", 1)[1]
    match = re.search(r"```python\n(.*?)```", section, re.S)
    assert match, "docs/robots.md: no python block under 'Adding a robot'"
    return match.group(1)


def test_the_fourth_robot_of_the_docs_is_one_spec_entry_and_runs_in_the_harness(scratch_names):
    scratch_names.append("xarm7")
    namespace: dict[str, object] = {}
    exec(compile(_docs_snippet(), str(DOCS), "exec"), namespace)  # the docs' own code, unchanged
    arm = robots.load("xarm7")
    assert arm.nq == 7 and arm.ee_frame == "link_eef"
    np.testing.assert_array_equal(arm.v_max, [3.14] * 7)  # the package URDF's <limit velocity>
    # ... and the harness runs it from a config: one second of the paper's case 2, kinematic.
    from compare.config import parse_config
    from compare.run import run_method

    config = parse_config(
        {
            "scenario": {
                "robot": "xarm7",
                "kind": "case2",
                "duration_s": 1.0,
                "simulation": "kinematic",
                "sensing": "geometric",
            },
            "levels": [
                {"name": "limits", "tasks": [{"type": "joint_limit", "joints": [2, 4, 6]}]},
                {
                    "name": "walls",
                    "tasks": [{"type": "wall_box", "lower": [-0.6, -0.6, 0.1], "upper": [0.6, 0.6, 1.0]}],
                },
                {"name": "obstacles", "tasks": [{"type": "obstacle_distance"}]},
                {"name": "operational", "tasks": [{"type": "position"}]},
            ],
            "methods": {"names": ["tpik"]},
        }
    )
    result = run_method(config, "tpik", arm)
    summary = result["summary"]
    assert summary["robot"] == "xarm7" and summary["control_points"] == ["link4", "link6", "link7"]
    assert summary["failures"] == summary["deadline_misses"]  # none but a late solve (the VM's CPU clock)
    assert summary["ee_error_m"]["final"] < 1e-3  # holds its start EE

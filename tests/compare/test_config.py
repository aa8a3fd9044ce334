"""Config validation: every user mistake is one clear line naming the key, exit code 2."""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

import pytest
import tomli_w
from typer.testing import CliRunner

from compare.cli import app
from compare.config import ConfigError, load_config, parse_config

CONFIGS = Path(__file__).resolve().parents[2] / "configs"


def _case1() -> dict:
    with open(CONFIGS / "case1.toml", "rb") as fh:
        return tomllib.load(fh)


def _set(data: dict, dotted: str, value: object) -> dict:
    node = data
    *parents, leaf = dotted.split(".")
    for key in parents:
        node = node[int(key)] if key.isdigit() else node.setdefault(key, {})
    node[leaf] = value
    return data


BAD_CONFIGS = [
    ("scenario.duraton_s", 10.0, r"scenario\.duraton_s: unknown key"),
    ("scenario.duration_s", -1.0, r"scenario\.duration_s: Input should be greater than 0"),
    ("scenario.duration_s", "long", r"scenario\.duration_s: Input should be a valid number"),
    ("scenario.sensing", "lidar", r"scenario\.sensing: Input should be 'depth' or 'geometric'"),
    ("scenario.start_q", [0.0, 1.0], r"scenario\.start_q"),
    ("sensor.dropout", 1.5, r"sensor\.dropout: Input should be less than 1"),
    (
        "methods.names",
        ["tpik", "hqp-nosuchsolver"],
        r"methods\.names\[1\]: unknown method 'hqp-nosuchsolver'; available:",
    ),
    ("methods.names", ["teleport"], r"unknown method 'teleport'"),
    ("methods.settings", {"hqp-osqp": {}}, r"settings for 'hqp-osqp', which is not in names"),
    (
        "levels.1.tasks",
        [{"type": "obstacle_distance", "frames": ["link_4"], "safety_distance": 0.05}],
        r"levels\[1\]\.tasks\[0\]\.safety_distance: must be > physical_distance=0.1 m, got 0.05$",
    ),
    (
        "levels.0.tasks",
        [{"type": "joint_limit", "joints": [1]}],
        r"levels\[0\]\.tasks\[0\]\.joints: joint 1 is continuous",
    ),
    (
        "levels.2.tasks",
        [{"type": "position", "frame": "elbow"}],
        r"levels\[2\]\.tasks\[0\]\.frame: unknown frame 'elbow'",
    ),
    (
        "levels.0.tasks",
        [{"type": "joint_limit", "joints": [2], "safety_margn": 0.1}],
        r"levels\[0\]\.tasks\[0\]: unknown key 'safety_margn' for task type joint_limit",
    ),
    ("scenario.robot", "ur10", r"scenario\.robot: unknown robot 'ur10'; available: jaco2, panda, ur5"),
    (
        "scenario.robot",
        "panda",
        r"levels\[\d\]\.tasks\[\d\]\.frames?: unknown frame 'link_4'",
    ),  # the Jaco²'s frames on a Panda
    ("scenario.start_q", [0.0] * 6, r"scenario\.start_q: 6 values for the 7 joints of 'jaco2'"),
    ("random.reach_targets", ["waypoint", "elbow"], r"random\.reach_targets\[1\]: 'elbow' is neither"),
    ("hardware.joint_names", ["a", "b"], r"hardware\.joint_names: 2 names for the 7 joints of 'jaco2'"),
]


@pytest.mark.parametrize(
    ("key", "value", "message"), BAD_CONFIGS, ids=[b[0] + "=" + str(b[1])[:20] for b in BAD_CONFIGS]
)
def test_bad_config_gives_one_line_naming_the_key(key, value, message):
    with pytest.raises(ConfigError, match=message) as info:
        parse_config(_set(_case1(), key, value))
    assert "\n" not in str(info.value)


@pytest.mark.parametrize(("key", "value", "message"), BAD_CONFIGS[:4] + BAD_CONFIGS[6:7] + BAD_CONFIGS[9:10])
def test_cli_exits_2_with_one_line_and_no_traceback(tmp_path, key, value, message):
    path = tmp_path / "bad.toml"
    path.write_text(tomli_w.dumps(_set(_case1(), key, value)))
    result = CliRunner().invoke(app, ["run", str(path), "--out", str(tmp_path / "out")])
    assert result.exit_code == 2
    err = result.stderr.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in result.output
    assert re.search(message, err)
    assert not (tmp_path / "out").exists()


def test_missing_file_and_bad_toml_are_one_line(tmp_path):
    with pytest.raises(ConfigError, match="cannot read config"):
        load_config(tmp_path / "nope.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("[scenario\nname = 1")
    with pytest.raises(ConfigError, match="invalid TOML"):
        load_config(bad)


SHIPPED = sorted(CONFIGS.glob("*.toml")) + sorted((CONFIGS.parent / "docs" / "examples").glob("*.toml"))


def test_the_shipped_configs_are_found():
    # The glob below must see the configs the README documents, or the next test checks nothing.
    assert {"case1.toml", "case2.toml", "random.toml", "faults.toml", "elbow_height.toml"} <= {p.name for p in SHIPPED}


@pytest.mark.parametrize("path", SHIPPED, ids=[p.name for p in SHIPPED])
def test_shipped_configs_are_valid(path):
    config, _ = load_config(path)
    assert config.levels and config.methods.names, path


def test_overrides_apply_dotted_keys():
    config, _ = load_config(CONFIGS / "case1.toml", {"scenario.time_scale": 0.25, "scenario.sensing": "geometric"})
    assert config.scenario.sim_time_s == pytest.approx(70.0 * 0.25)
    assert config.scenario.sensing == "geometric"


def test_overrides_are_in_the_returned_text_and_reproduce_the_config():
    plain, text = load_config(CONFIGS / "random.toml")
    assert text == (CONFIGS / "random.toml").read_text(encoding="utf-8")
    cfg, text = load_config(CONFIGS / "random.toml", {"scenario.simulation": "kinematic", "scenario.seed": 5})
    assert plain.scenario.simulation == "dynamic" and cfg.scenario.simulation == "kinematic"
    assert text.startswith("# random.toml with command-line overrides")
    assert parse_config(tomllib.loads(text)) == cfg


@pytest.mark.parametrize(
    ("option", "value", "bad"), [("simulation", "kinematic", "quantum"), ("drive", "servo", "hydraulic")]
)
def test_cli_scenario_option_is_applied_recorded_and_checked(tmp_path, option, value, bad):
    """--simulation / --drive land in the run's config.toml; a bad value is one line and exit 2."""
    out = tmp_path / "out"
    args = ["run", str(CONFIGS / "case1.toml"), "--out", str(out), "-q", "--no-plots", "--duration", "0.2"]
    result = CliRunner().invoke(app, [*args, "--sensing", "geometric", f"--{option}", value, "-m", "tpik"])
    assert result.exit_code == 0, result.output
    saved = tomllib.loads((out / "config.toml").read_text(encoding="utf-8"))
    assert saved["scenario"][option] == value and saved["scenario"]["sensing"] == "geometric"
    rejected = CliRunner().invoke(app, [*args, f"--{option}", bad])
    assert rejected.exit_code == 2 and option in rejected.stderr and "Traceback" not in rejected.output


def test_a_drive_bandwidth_the_physics_step_cannot_integrate_is_a_config_error(tmp_path):
    with pytest.raises(ConfigError, match="drive_bandwidth_rad_s"):
        load_config(CONFIGS / "random.toml", {"scenario.drive_bandwidth_rad_s": 1000.0})


@pytest.mark.parametrize(
    ("name", "robot", "ee", "cps"),
    [
        ("case1.toml", "jaco2", "end_effector", ["link_4", "link_6", "link_7"]),
        ("panda_case1.toml", "panda", "panda_hand_tcp", ["panda_link4", "panda_link6", "panda_link7"]),
        ("panda_case2.toml", "panda", "panda_hand_tcp", ["panda_link4", "panda_link6", "panda_link7"]),
        ("panda_random.toml", "panda", "panda_hand_tcp", ["panda_link4", "panda_link6", "panda_link7"]),
        ("ur5_case2.toml", "ur5", "tool0", ["forearm_link", "wrist_2_link", "wrist_3_link"]),
    ],
)
def test_each_robot_config_builds_its_hierarchy_on_its_robot(name, robot, ee, cps):
    from compare.loop.closed_loop import control_points

    config, _ = load_config(CONFIGS / name)
    arm = config.load_robot()
    assert arm.name == robot and arm.ee_frame == ee
    hierarchy = config.build_hierarchy(arm)
    assert list(control_points(hierarchy, arm)) == cps
    assert config.hardware.joint_names == arm.joint_names  # default: the description's joints
    if config.scenario.start_q is not None:
        assert len(config.scenario.start_q) == arm.nq


def test_tasks_without_frames_use_the_robot_s_ee_and_control_points():
    from tpik.tasks import ObstacleDistanceTask, PositionTask

    data = _case1()
    data["scenario"]["robot"] = "ur5"
    data["levels"] = [
        {"name": "obstacles", "tasks": [{"type": "obstacle_distance"}]},
        {"name": "operational", "tasks": [{"type": "position"}]},
    ]
    config = parse_config(data)
    hierarchy = config.build_hierarchy(config.load_robot())
    assert [t.frame for t in hierarchy.tasks if isinstance(t, ObstacleDistanceTask)] == [
        "forearm_link",
        "wrist_2_link",
        "wrist_3_link",
    ]
    assert [t.frame for t in hierarchy.tasks if isinstance(t, PositionTask)] == ["tool0"]

"""One error root per package, and the CLI's one-line answer to each of them."""

from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import CliRunner

import compare.run
import qp_baseline
import tpik
from compare.analysis.metrics import MetricsError
from compare.campaign.executors import ExecutorUnavailable
from compare.cli import USER_ERRORS, app
from compare.config import ConfigError, load_config
from compare.exceptions import CompareError
from compare.hardware.exceptions import HardwareError, MasterUnreachable, RosUnavailable, StartRefused
from compare.methods import UnknownMethod
from compare.sensing.exceptions import SensingError, UnknownSceneElement
from qp_baseline.exceptions import HqpError, NoSolutionFound, UnknownSolver
from robots.exceptions import RobotError, UnknownFrame
from tpik.exceptions import InvalidSettings, TaskDefinitionError, TpikError

CONFIGS = Path(__file__).resolve().parents[2] / "configs"


@pytest.mark.parametrize(
    ("error", "bases"),
    [
        (ConfigError, (CompareError, ValueError)),
        (ExecutorUnavailable, (ConfigError,)),
        (MetricsError, (CompareError, ValueError)),
        (UnknownMethod, (CompareError, ValueError)),
        (SensingError, (CompareError,)),
        (UnknownSceneElement, (SensingError,)),
        (HardwareError, (CompareError, RuntimeError)),
        (RosUnavailable, (HardwareError,)),
        (MasterUnreachable, (HardwareError,)),
        (StartRefused, (HardwareError,)),
        (UnknownSolver, (HqpError, ValueError)),
        (NoSolutionFound, (HqpError,)),
        (TaskDefinitionError, (TpikError, ValueError)),
        (InvalidSettings, (TpikError, ValueError)),
        (UnknownFrame, (RobotError,)),
    ],
)
def test_every_error_sits_under_its_package_root(error, bases):
    assert all(issubclass(error, base) for base in bases)


def test_there_is_one_invalid_settings():
    assert qp_baseline.InvalidSettings is tpik.InvalidSettings is InvalidSettings
    assert str(InvalidSettings("daqp", "bad value", "eps")) == "daqp: bad value"
    assert InvalidSettings("daqp", "bad value", "eps").key == "eps"
    assert str(InvalidSettings("variant: unknown")) == "variant: unknown"


@pytest.mark.parametrize(
    "error",
    [
        ConfigError("scenario.x: unknown key"),
        HardwareError("no camera"),
        TaskDefinitionError("levels[0].tasks[0].joints: must list at least one entry"),
        UnknownFrame("elbow", ["link_4"]),
        UnknownSolver("nope", ["daqp"]),
    ],
    ids=lambda e: type(e).__name__,
)
def test_cli_turns_every_package_error_into_one_line_and_exit_2(monkeypatch, tmp_path, error):
    def fail(*args, **kwargs):
        raise error

    monkeypatch.setattr(compare.run, "run_scenario", fail)
    args = ["run", str(CONFIGS / "case1.toml"), "--out", str(tmp_path / "o"), "-q", "-m", "tpik"]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 2
    assert result.stderr.strip() == f"error: {error}"
    assert "Traceback" not in result.output
    assert isinstance(error, USER_ERRORS)


def test_cli_lets_a_bug_surface_with_its_traceback(monkeypatch, tmp_path):
    def fail(*args, **kwargs):
        raise ZeroDivisionError("a bug")

    monkeypatch.setattr(compare.run, "run_scenario", fail)
    args = ["run", str(CONFIGS / "case1.toml"), "--out", str(tmp_path / "o"), "-q", "-m", "tpik"]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 1 and isinstance(result.exception, ZeroDivisionError)


def _with_extension(tmp_path: Path, entry: str) -> Path:
    text = (CONFIGS / "case1.toml").read_text(encoding="utf-8")
    path = tmp_path / "cfg" / "scenario.toml"
    path.parent.mkdir(exist_ok=True)
    path.write_text(f'[extensions]\nmodules = ["{entry}"]\n\n' + text, encoding="utf-8")
    return path


@pytest.mark.parametrize(
    ("entry", "source", "match"),
    [
        ("no_such_module_xyz", None, r"^extensions\.modules\[0\]: cannot import 'no_such_module_xyz'"),
        ("missing.py", None, r"^extensions\.modules\[0\]: no Python file .*missing\.py"),
        ("broken.py", "raise RuntimeError('half-written')", r"^extensions\.modules\[0\]: .*RuntimeError: half-written"),
    ],
)
def test_a_bad_extension_module_is_one_config_error(tmp_path, entry, source, match):
    path = _with_extension(tmp_path, entry)
    if source is not None:
        (path.parent / entry).write_text(source, encoding="utf-8")
    with pytest.raises(ConfigError, match=match):
        load_config(path)


def test_an_extension_file_is_found_next_to_its_config(tmp_path, monkeypatch):
    from tpik.tasks import registry

    monkeypatch.setattr(registry, "_REGISTRY", dict(registry._REGISTRY))
    path = _with_extension(tmp_path, "marker.py")
    (path.parent / "marker.py").write_text(
        "import tpik\nfrom tpik.tasks.joint_limit_task import JOINT_LIMIT_KEYS, build_joint_limits\n"
        "tpik.register_task('joint_limit_copy', build_joint_limits, keys=JOINT_LIMIT_KEYS, example={})\n",
        encoding="utf-8",
    )
    monkeypatch.chdir(tmp_path)  # not the config's folder
    config, _ = load_config(path)
    assert config.extensions.modules == [str((path.parent / "marker.py").resolve())]
    assert "joint_limit_copy" in [t.name for t in tpik.task_types()]

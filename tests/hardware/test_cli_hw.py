"""``tpik-compare hw`` checks that need no ROS: they refuse before connecting."""

from __future__ import annotations

import subprocess
import sys

from tests.hardware.conftest import ROOT, write_config


def _refused_start(config, out):
    """``tpik-compare hw CONFIG`` without ROS: the checks that refuse before connecting."""
    return subprocess.run(
        [sys.executable, "-m", "compare.cli", "hw", str(config), "--out", str(out), "-q"],
        cwd=ROOT, capture_output=True, text=True, timeout=120,
    )  # fmt: skip


def test_start_refused_without_camera_transform(tmp_path):
    config = write_config(tmp_path / "nocam.toml", scenario={"time_scale": 0.1}, methods={"names": ["tpik"]})
    res = _refused_start(config, tmp_path / "hw")
    assert res.returncode == 2, res.stderr
    assert "camera transform missing" in res.stderr and "Traceback" not in res.stderr
    assert res.stderr.count("\n") == 1


def test_hw_help_lists_the_options():
    res = subprocess.run(
        [sys.executable, "-m", "compare.cli", "hw", "--help"], cwd=ROOT, capture_output=True, text=True, timeout=60
    )
    assert res.returncode == 0
    for option in ("--method", "--dry-run", "--duration", "--out"):
        assert option in res.stdout


def test_start_refused_with_several_cameras_in_one_line(tmp_path):
    config = write_config(
        tmp_path / "two.toml", base="case1_two_cameras.toml", scenario={"time_scale": 0.1}, methods={"names": ["tpik"]}
    )
    res = _refused_start(config, tmp_path / "hw")
    assert res.returncode == 2, res.stderr
    assert "2 cameras in [[sensor.cameras]]" in res.stderr and "Traceback" not in res.stderr
    assert res.stderr.count("\n") == 1
    assert not (tmp_path / "hw").exists()  # refused before the results directory was made

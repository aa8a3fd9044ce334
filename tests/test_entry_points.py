"""Every ``python -m`` entry point and script checks its arguments: ``--help`` works, a bad option or a
missing input is one line on stderr and exit status 2, never a traceback.

Each case starts a fresh interpreter in a temporary directory, so nothing in the checkout is written.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

MODULES = [
    "compare.analysis.prediction_quality",
    "compare.analysis.readme_figures",
    "compare.analysis.violations",
    "compare.bench.occlusion",
    "compare.bench.qp_reference",
    "compare.bench.sensing",
    "compare.campaign.cameras",
    "compare.campaign.setups",
    "compare.config_doc",
    "compare.hardware.driver_model",
    "compare.hardware.standin",
]
SCRIPTS = ["scripts/loop_parts.py", "scripts/plant_bench.py"]
MISSING_INPUT = {
    "compare.analysis.prediction_quality": ["/no/such/run"],
    "compare.analysis.violations": ["/no/such/run"],
    "compare.bench.occlusion": ["--config", "/no/such.toml"],
    "compare.campaign.cameras": ["/no/such/one", "/no/such/two", "--out", "out"],
    "compare.campaign.setups": ["/no/such/a", "/no/such/b", "--out", "out"],
    "compare.hardware.standin": ["/no/such.toml"],
    "scripts/loop_parts.py": ["--family", "/no/such.toml"],
    "scripts/plant_bench.py": ["--sweep", "/no/such/sweep"],
}


def _run(target: str, args: list[str], cwd: Path) -> subprocess.CompletedProcess[str]:
    command = [sys.executable, str(ROOT / target)] if target.endswith(".py") else [sys.executable, "-m", target]
    env = {**os.environ, "PYTHONPATH": str(ROOT), "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    return subprocess.run([*command, *args], cwd=cwd, env=env, capture_output=True, text=True, timeout=120)


@pytest.mark.parametrize("target", MODULES + SCRIPTS)
def test_help_and_a_bad_option(target: str, tmp_path: Path) -> None:
    shown = _run(target, ["--help"], tmp_path)
    assert shown.returncode == 0 and "usage" in shown.stdout.lower(), shown.stderr
    bad = _run(target, ["--no-such-option"], tmp_path)
    assert bad.returncode == 2
    assert "Traceback" not in bad.stderr and bad.stderr.strip().splitlines()[-1]
    assert list(tmp_path.iterdir()) == []  # nothing written


@pytest.mark.parametrize("target", sorted(MISSING_INPUT))
def test_a_missing_input_is_one_line(target: str, tmp_path: Path) -> None:
    result = _run(target, MISSING_INPUT[target], tmp_path)
    assert result.returncode == 2, result.stdout + result.stderr
    assert "Traceback" not in result.stderr
    assert "/no/such" in result.stderr.strip().splitlines()[-1]

"""Every ``python -m`` entry point and script checks its arguments before any work starts.

``--help`` exits 0 with the usage and a description; an unknown option, and a path that does not
exist where the tool reads one, exit 2 with one ``error: ...`` line on stderr and no traceback.
Each case is a fresh interpreter whose working directory is an empty temporary directory (the
checkout reached through ``PYTHONPATH``), which must stay empty: nothing is written.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

MISSING = "/no/such"

ENTRY_POINTS: dict[str, list[str] | None] = {
    # entry point -> arguments naming a missing input (None: the tool reads no path)
    "compare.analysis.prediction_quality": [f"{MISSING}/run"],
    "compare.analysis.reading_error": [f"{MISSING}/run"],
    "compare.analysis.readme_figures": ["--root", f"{MISSING}/checkout"],
    "compare.analysis.violations": [f"{MISSING}/run"],
    "compare.bench.occlusion": ["--config", f"{MISSING}.toml"],
    "compare.bench.qp_export": None,
    "compare.bench.qp_reference": None,
    "compare.bench.sensing": None,
    "compare.campaign.cameras": [f"{MISSING}/one", f"{MISSING}/two", "--out", "out"],
    "compare.campaign.setups": [f"{MISSING}/a", f"{MISSING}/b", "--out", "out"],
    "compare.config_doc": None,
    "compare.hardware.driver_model": None,
    "compare.hardware.standin": [f"{MISSING}.toml"],
    "scripts/loop_parts.py": ["--family", f"{MISSING}.toml"],
    "scripts/plant_bench.py": ["--sweep", f"{MISSING}/sweep"],
}
SLOW = {"compare.campaign.cameras", "compare.campaign.setups", "compare.hardware.standin", "scripts/loop_parts.py"}
"""The entry points whose imports take longest (5–8 s for their three interpreters on one core)."""


def _run(target: str, args: list[str], cwd: Path) -> subprocess.CompletedProcess[str]:
    command = [sys.executable, str(ROOT / target)] if target.endswith(".py") else [sys.executable, "-m", target]
    env = {**os.environ, "PYTHONPATH": str(ROOT), "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    return subprocess.run([*command, *args], cwd=cwd, env=env, capture_output=True, text=True, timeout=120)


def _one_line_error(result: subprocess.CompletedProcess[str], names: str) -> None:
    assert result.returncode == 2, result.stdout + result.stderr
    assert "Traceback" not in result.stderr, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and names in lines[0], result.stderr


@pytest.mark.parametrize(
    "target", [pytest.param(t, marks=pytest.mark.slow) if t in SLOW else t for t in sorted(ENTRY_POINTS)]
)
def test_help_works_and_bad_input_is_one_line_with_exit_2(target: str, tmp_path: Path) -> None:
    shown = _run(target, ["--help"], tmp_path)
    assert shown.returncode == 0, shown.stderr
    usage, _, rest = shown.stdout.partition("\n\n")
    assert usage.startswith("usage: ") and rest.strip() and not rest.startswith("options:"), shown.stdout
    _one_line_error(_run(target, ["--no-such-option"], tmp_path), "--no-such-option")
    missing = ENTRY_POINTS[target]
    if missing is not None:
        _one_line_error(_run(target, missing, tmp_path), MISSING)
    assert list(tmp_path.iterdir()) == []  # nothing written

"""``summary.json`` and ``sweep_summary.json`` keep their keys and values (docs/design.md §7).

The files in ``reference/`` were written by the code at commit d25a909, before the metrics moved
into a registry (``compare.analysis.metric``), with::

    export OPENBLAS_CORETYPE=Haswell   # as tests/conftest.py
    tpik-compare run configs/faults.toml --sensing geometric --simulation kinematic -q --no-plots \
        --out faults_run                                   # → reference/faults_run.json
    tpik-compare run configs/case2.toml --time-scale 0.3 --sensing geometric --simulation kinematic \
        -q --no-plots -m tpik -m hqp-daqp --out case2_run  # → reference/case2_run.json
    tpik-compare sweep configs/random.toml -n 3 -w 1 --duration 6 -m tpik -m hqp-daqp -m mink \
        --out sweep                                        # → reference/runs/*.json, sweep_summary.json,
                                                           #   sweep_runs.csv

A run is simulated again and its ``summary.json`` compared with the reference: the same keys at
every depth, the same values outside the machine-dependent ones (:data:`TIMING_KEYS`). The sweep
aggregation is recomputed from the reference runs' summaries and must give the same
``sweep_summary.json`` and ``sweep_runs.csv``.
"""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path
from typing import Any

import pandas as pd
import pytest
from typer.testing import CliRunner

from compare.analysis.results import deterministic_view, sweep_run_dir, write_sweep_summary
from compare.cli import app

REFERENCE = Path(__file__).resolve().parent / "reference"
CONFIGS = Path(__file__).resolve().parents[3] / "configs"
RUNS = {
    "faults_run": ["run", str(CONFIGS / "faults.toml"), "--sensing", "geometric", "--simulation", "kinematic"],
    "case2_run": [
        "run",
        str(CONFIGS / "case2.toml"),
        "--time-scale",
        "0.3",
        "--sensing",
        "geometric",
        "--simulation",
        "kinematic",
        "-m",
        "tpik",
        "-m",
        "hqp-daqp",
    ],
}
MACHINE = frozenset({"versions"})
"""Entries whose very keys depend on the checkout and the machine (``git_commit``, CPU)."""
ADDED_CONFIG_SECTIONS = ("prediction.",)
"""Config sections added after the reference was written: their keys appear in ``config_fingerprint``
(keys are only ever added); at their defaults they must not change any other value."""
SWEEP_RUN_ENTRIES = frozenset({"campaign", "person", "skipped_finished_runs"})
"""Entries of ``sweep_summary.json`` that ``run_sweep`` adds beside the aggregation."""


def _without_added_sections(summary: dict[str, Any]) -> dict[str, Any]:
    """``summary`` without the fingerprint keys of :data:`ADDED_CONFIG_SECTIONS` (checked at their defaults)."""
    fingerprint = dict(summary.get("config_fingerprint", {}))
    added = {k: fingerprint.pop(k) for k in list(fingerprint) if k.startswith(ADDED_CONFIG_SECTIONS)}
    if "prediction.mode" in added:
        assert added["prediction.mode"] == "off", added
    return {**summary, "config_fingerprint": fingerprint} if "config_fingerprint" in summary else summary


def _key_tree(value: Any) -> Any:
    """The keys of ``value`` at every depth (dicts → key trees, lists → their items' trees)."""
    if isinstance(value, dict):
        return {k: _key_tree(v) for k, v in value.items() if k not in MACHINE}
    if isinstance(value, list):
        return [_key_tree(v) for v in value]
    return None


def _assert_same_values(actual: Any, expected: Any, where: str = "") -> None:
    """Equal, floats within 1e-9 relative (the same arithmetic on another BLAS may round differently)."""
    if isinstance(expected, dict):
        assert isinstance(actual, dict) and set(actual) == set(expected), where
        for key, value in expected.items():
            _assert_same_values(actual[key], value, f"{where}.{key}")
    elif isinstance(expected, list):
        assert isinstance(actual, list) and len(actual) == len(expected), where
        for k, (a, e) in enumerate(zip(actual, expected, strict=True)):
            _assert_same_values(a, e, f"{where}[{k}]")
    elif isinstance(expected, float) and not isinstance(actual, bool):
        assert actual == pytest.approx(expected, rel=1e-9, abs=1e-12), where
    else:
        assert actual == expected, where


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(RUNS))
def test_a_run_writes_the_summary_of_the_reference(tmp_path: Path, name: str) -> None:
    out = tmp_path / name
    result = CliRunner().invoke(app, [*RUNS[name], "-q", "--no-plots", "--out", str(out)])
    assert result.exit_code == 0, result.output
    actual = _without_added_sections(json.loads((out / "summary.json").read_text(encoding="utf-8")))
    expected = json.loads((REFERENCE / f"{name}.json").read_text(encoding="utf-8"))
    assert _key_tree(actual) == _key_tree(expected)
    _assert_same_values(deterministic_view(actual), deterministic_view(expected))


def test_the_sweep_aggregation_of_the_reference_runs_is_unchanged(tmp_path: Path) -> None:
    for k, path in enumerate(sorted((REFERENCE / "runs").glob("*.json"))):
        run_dir = sweep_run_dir(tmp_path, k)
        run_dir.mkdir(parents=True)
        shutil.copy(path, run_dir / "summary.json")
    actual = write_sweep_summary(tmp_path)
    expected = json.loads((REFERENCE / "sweep_summary.json").read_text(encoding="utf-8"))
    assert set(actual) == set(expected) - SWEEP_RUN_ENTRIES
    assert _key_tree(actual) == {k: v for k, v in _key_tree(expected).items() if k not in SWEEP_RUN_ENTRIES}
    for key in set(actual) - MACHINE:
        _assert_same_values(actual[key], expected[key], key)
    rows = pd.read_csv(tmp_path / "sweep_runs.csv", dtype={"run": str})
    reference = pd.read_csv(REFERENCE / "sweep_runs.csv", dtype={"run": str})
    assert set(rows.columns) == set(reference.columns)
    pd.testing.assert_frame_equal(rows[list(reference.columns)], reference, check_exact=False, rtol=1e-12)


def test_the_reference_files_hold_every_design_key() -> None:
    """The references are worth comparing against: docs/design.md §7's keys are in them, not all empty."""
    summary = json.loads((REFERENCE / "faults_run.json").read_text(encoding="utf-8"))
    tpik = summary["methods"]["tpik"]
    for key in ("solve_time_us", "joint_limits", "obstacles", "ee_error_m", "status_steps", "iso15066", "faults"):
        assert tpik[key], key
    assert tpik["failures"] > 0 and tpik["obstacles"]["violations"] > 0
    sweep = json.loads((REFERENCE / "sweep_summary.json").read_text(encoding="utf-8"))
    assert {"tpik", "hqp-daqp", "mink"} == set(sweep["methods"]) and sweep["paired"]
    assert not math.isnan(sweep["methods"]["tpik"]["solve_time_us"]["median_of_medians"])

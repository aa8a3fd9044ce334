"""Reading errors of the measured obstacle distances against the truth (compare.analysis.reading_error)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from compare.analysis.reading_error import main, reading_errors, step_errors, summarize_errors


def _steps(truth: list[float], meas: list[float], occluded: list[bool]) -> pd.DataFrame:
    return pd.DataFrame(
        {"t": np.arange(len(truth)) * 0.01, "dist_true:p": truth, "dist_meas:p": meas, "occluded:p": occluded}
    )


def _run(root: Path, name: str, methods: dict[str, pd.DataFrame]) -> Path:
    run = root / name
    (run / "steps").mkdir(parents=True)
    for method, steps in methods.items():
        steps.to_parquet(run / "steps" / f"{method}.parquet", index=False)
    (run / "summary.json").write_text(json.dumps({"methods": {m: {} for m in methods}}), encoding="utf-8")
    return run


def test_only_steps_with_the_person_within_count_and_a_missing_reading_is_missed() -> None:
    steps = _steps(
        truth=[0.30, 0.40, 0.44, 0.60, 0.20],
        meas=[0.28, 0.45, np.inf, 0.10, 0.20],
        occluded=[True, False, False, True, False],
    )
    errors, occluded, missed = step_errors(steps, within_m=0.45)
    np.testing.assert_allclose(np.sort(errors), [-0.02, 0.0, 0.05], atol=1e-12)  # 0.60 m is outside 0.45
    assert (occluded, missed) == (1, 1)
    figures = summarize_errors(errors, occluded, missed)
    assert figures["samples"] == 4
    assert figures["largest_over_mm"] == pytest.approx(50.0)
    assert figures["short_share"] == pytest.approx(1 / 3)  # -20 mm is short by more than 1 cm
    assert figures["far_share"] == pytest.approx(1 / 3)  # +50 mm
    assert figures["missed_share"] == pytest.approx(1 / 4)
    assert figures["median_mm"] == pytest.approx(0.0, abs=1e-9)


def test_a_sweep_pools_its_runs_per_method_and_the_method_filter_holds(tmp_path: Path) -> None:
    exact = _steps([0.3, 0.3], [0.3, 0.3], [False, False])
    short = _steps([0.3, 0.3], [0.2, 0.2], [False, False])
    _run(tmp_path / "sweep" / "runs", "00000", {"a": exact, "b": short})
    _run(tmp_path / "sweep" / "runs", "00001", {"a": short, "b": short})
    rows = {r["method"]: r for r in reading_errors(tmp_path / "sweep")}
    assert rows["a"]["runs"] == 2 and rows["a"]["samples"] == 4
    assert rows["a"]["short_share"] == pytest.approx(0.5)
    assert rows["b"]["mean_mm"] == pytest.approx(-100.0)
    assert [r["method"] for r in reading_errors(tmp_path / "sweep", methods=["b"])] == ["b"]
    assert reading_errors(tmp_path / "sweep", max_runs=1)[0]["samples"] == 2


def test_the_command_prints_and_writes_the_rows(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    run = _run(tmp_path, "run", {"tpik": _steps([0.3], [0.35], [False])})
    out = tmp_path / "errors.json"
    assert main([str(run), "--json", str(out)]) == 0
    assert "tpik" in capsys.readouterr().out
    rows = json.loads(out.read_text(encoding="utf-8"))
    assert rows[0]["largest_over_mm"] == pytest.approx(50.0)


def test_a_directory_without_runs_is_one_error(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_info:
        main([str(tmp_path)])
    assert exit_info.value.code == 2
    assert "neither a run" in capsys.readouterr().err

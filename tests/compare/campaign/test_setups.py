"""Setups compared on the same seeds: held rates, the paired McNemar counts, mission cost, the CLI."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from compare.analysis.results import sweep_run_dir
from compare.campaign.setups import compare_setups, main


def _sweep(root: Path, held: dict[int, bool], ee: float, label: str | None = "avoidable") -> Path:
    """A sweep of one method whose run of seed s held the threshold when ``held[s]``."""
    for k, (seed, ok) in enumerate(sorted(held.items())):
        run = sweep_run_dir(root, k)
        run.mkdir(parents=True)
        method = {
            "obstacles": {"violations": 0 if ok else 3, "physical_violation_time_s": 0.0 if ok else 0.2},
            "joint_limits": {"violations": 0, "safety_margin_min": 0.01 + 0.001 * k},
            "walls": {"violations": int(k == 0), "safety_margin_min": -0.002 if k == 0 else 0.01},
            "ee_error_m": {"mean": ee + 0.001 * k, "final": 0.0},
            "waypoints_reached": 2,
        }
        summary = {"seed": seed, "methods": {"tpik": method}, "oracle": {"label": label}}
        (run / "summary.json").write_text(json.dumps(summary), encoding="utf-8")
    return root


def test_paired_counts_rates_and_mission_cost(tmp_path: Path) -> None:
    off = _sweep(tmp_path / "off", {s: s < 2 for s in range(10)}, ee=0.20)  # held 0, 1
    on = _sweep(tmp_path / "on", {s: s % 2 == 0 for s in range(12)}, ee=0.25)  # held 0, 2, 4, 6, 8 (+10)
    result = compare_setups([("off", off), ("on", on)])
    m = result["methods"]["tpik"]
    assert m["paired_runs"] == 10 and m["seeds"] == [0, 9]  # seeds 10, 11 are not in the baseline
    e_on, e_off = m["setups"]["on"], m["setups"]["off"]
    assert e_on["held"]["count"] == 5 and e_off["held"]["count"] == 2
    assert e_on["held"]["ci95"][0] < 0.5 < e_on["held"]["ci95"][1]
    assert e_on["held_avoidable"]["count"] == 5
    assert (e_on["vs_baseline"]["only_this"], e_on["vs_baseline"]["only_baseline"]) == (4, 1)  # 2,4,6,8 / 1
    assert e_on["vs_baseline"]["mcnemar_p"] == pytest.approx(0.375)
    assert e_on["ee_error_mean_m"] == pytest.approx(0.25 + 0.0045)
    assert e_on["ee_error_vs_baseline_wilcoxon_p"] < 0.01  # 0.05 m more, every seed
    assert e_on["wall_violations"] == 1 and e_on["wall_margin_min_m"] == pytest.approx(-0.002)


def test_no_verdict_no_avoidable_rate_and_bad_input_is_one_line(tmp_path: Path, capsys) -> None:
    a = _sweep(tmp_path / "a", {0: True, 1: False}, ee=0.1, label=None)
    b = _sweep(tmp_path / "b", {0: False, 1: False}, ee=0.1, label=None)
    assert compare_setups([("a", a), ("b", b)])["methods"]["tpik"]["setups"]["b"]["held_avoidable"] is None
    assert main([str(a), str(tmp_path / "missing"), "--out", str(tmp_path / "out")]) == 2
    assert "no runs/ directory" in capsys.readouterr().err
    assert main([f"{a}:x", f"{b}:x", "--out", str(tmp_path / "out")]) == 2
    assert main([f"{a}:a", f"{b}:b", "--out", str(tmp_path / "out")]) == 0
    assert "| `tpik` | b | 2 |" in (tmp_path / "out" / "setups.md").read_text(encoding="utf-8")

"""Avoidable / unavoidable obstacle violations, Wilson intervals, the sweep aggregate and report."""

from __future__ import annotations

import json

from compare.analysis.avoidability import (
    has_oracle,
    oracle_sweep_summary,
    report_lines,
    split_obstacle_violations,
)
from compare.analysis.statistics import rate


def test_rate_has_the_design_keys_and_none_without_runs():
    r = rate(3, 10)
    assert set(r) == {"count", "runs", "rate", "ci95"} and r["rate"] == 0.3
    assert rate(0, 0) == {"count": 0, "runs": 0, "rate": None, "ci95": None}


def test_violations_are_avoidable_only_when_the_oracle_held():
    method = {"obstacles": {"violations": 4}}
    assert split_obstacle_violations(method, {"held_safety": True}) == {"avoidable": 4, "unavoidable": 0}
    assert split_obstacle_violations(method, {"held_safety": False}) == {"avoidable": 0, "unavoidable": 4}
    assert split_obstacle_violations({"obstacles": None}, {"held_safety": True}) == {"avoidable": 0, "unavoidable": 0}


def _write_run(sweep, index, oracle, methods):
    run = sweep / "runs" / f"{index:05d}"
    run.mkdir(parents=True)
    summary = {"scenario": "s", "seed": index, "methods": methods}
    if oracle is not None:
        summary["oracle"] = oracle
    (run / "summary.json").write_text(json.dumps(summary))
    return run


def test_sweep_aggregate_counts_runs_and_draws(tmp_path):
    viol = {"obstacles": {"violations": 2}}
    clean = {"obstacles": {"violations": 0}}
    _write_run(tmp_path, 0, {"held_safety": True, "min_distance_m": 0.5, "draws": 1}, {"a": viol, "b": clean})
    _write_run(tmp_path, 1, {"held_safety": False, "min_distance_m": 0.2, "draws": 3}, {"a": viol, "b": viol})
    _write_run(
        tmp_path,
        2,
        {"held_safety": True, "min_distance_m": 0.4, "draws": 2, "avoidable_draw_found": True},
        {"a": clean, "b": viol},
    )
    no_oracle = _write_run(tmp_path, 3, None, {"a": viol})
    assert not has_oracle(no_oracle) and has_oracle(tmp_path / "runs" / "00000")
    out = oracle_sweep_summary(tmp_path)
    assert out["oracle"]["runs"] == 3
    assert out["oracle"]["held_safety"]["count"] == 2
    assert out["oracle"]["min_distance_m"] == {"min": 0.2, "median": 0.4}
    assert out["oracle"]["draws"]["total"] == 6 and out["oracle"]["draws"]["rejected"] == 3
    a = out["methods"]["a"]["obstacle_violations"]
    b = out["methods"]["b"]["obstacle_violations"]
    assert (a["avoidable"]["count"], a["unavoidable"]["count"], a["avoidable"]["runs"]) == (1, 1, 3)
    assert (b["avoidable"]["count"], b["unavoidable"]["count"]) == (1, 1)
    assert a["episodes"] == {"avoidable": 2, "unavoidable": 2}
    assert a["avoidable_given_held"]["runs"] == 2 and a["unavoidable_given_not_held"]["runs"] == 1
    text = "\n".join(report_lines({"oracle": out["oracle"], "methods": out["methods"]}))
    assert "2/3 = 66.7 %" in text and "| a | 1/3 = 33.3 %" in text and "rejection rate 50.0 %" in text


def test_no_oracle_no_aggregate(tmp_path):
    _write_run(tmp_path, 0, None, {"a": {"obstacles": {"violations": 1}}})
    assert oracle_sweep_summary(tmp_path) is None
    assert report_lines({"methods": {}}) == []

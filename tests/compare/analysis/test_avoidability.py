"""Obstacle violations by the run's label, Wilson intervals, paired tests, the sweep aggregate and report."""

from __future__ import annotations

import json

from compare.analysis.avoidability import (
    has_oracle,
    oracle_sweep_summary,
    report_lines,
    run_label,
    split_obstacle_violations,
)
from compare.analysis.statistics import rate


def test_rate_has_the_design_keys_and_none_without_runs():
    r = rate(3, 10)
    assert set(r) == {"count", "runs", "rate", "ci95"} and r["rate"] == 0.3
    assert rate(0, 0) == {"count": 0, "runs": 0, "rate": None, "ci95": None}


def test_violations_are_counted_under_the_runs_label():
    method = {"obstacles": {"violations": 4}}
    assert split_obstacle_violations(method, {"label": "avoidable"}) == {
        "avoidable": 4,
        "unavoidable": 0,
        "undecided": 0,
    }
    assert split_obstacle_violations(method, {"label": "unavoidable"})["unavoidable"] == 4
    assert split_obstacle_violations(method, {"label": "undecided"})["undecided"] == 4
    assert split_obstacle_violations({"obstacles": None}, {"label": "avoidable"})["avoidable"] == 0
    # An entry without a label (an older oracle): held → avoidable; not held proves nothing → undecided.
    assert run_label({"held_safety": True}) == "avoidable" and run_label({"held_safety": False}) == "undecided"


def _write_run(sweep, index, oracle, methods):
    run = sweep / "runs" / f"{index:05d}"
    run.mkdir(parents=True)
    summary = {"scenario": "s", "seed": index, "methods": methods}
    if oracle is not None:
        summary["oracle"] = oracle
    (run / "summary.json").write_text(json.dumps(summary))
    return run


def test_sweep_aggregate_counts_labels_witnesses_and_draws(tmp_path):
    viol = {"obstacles": {"violations": 2}}
    clean = {"obstacles": {"violations": 0}}
    w = {"preview-1s": {"held": True}}
    _write_run(
        tmp_path,
        0,
        {"label": "avoidable", "witness": "preview-1s", "min_distance_m": 0.5, "draws": 1, "witnesses": w},
        {"a": viol, "b": clean},
    )
    _write_run(
        tmp_path,
        1,
        {
            "label": "undecided",
            "witness": None,
            "min_distance_m": 0.2,
            "draws": 3,
            "witnesses": {"preview-1s": {"held": False}, "oracle-2s": {"held": False}},
        },
        {"a": viol, "b": viol},
    )
    _write_run(
        tmp_path,
        2,
        {
            "label": "avoidable",
            "witness": "preview-1s",
            "min_distance_m": 0.4,
            "draws": 2,
            "avoidable_draw_found": True,
            "witnesses": w,
        },
        {"a": clean, "b": viol},
    )
    _write_run(
        tmp_path,
        3,
        {"label": "unavoidable", "min_distance_m": 0.1, "certificate": {"time_s": 1.0}},
        {"a": viol, "b": viol},
    )
    no_oracle = _write_run(tmp_path, 4, None, {"a": viol})
    assert not has_oracle(no_oracle) and has_oracle(tmp_path / "runs" / "00000")
    out = oracle_sweep_summary(tmp_path)
    assert out["oracle"]["runs"] == 4
    labels = out["oracle"]["labels"]
    assert (labels["avoidable"]["count"], labels["unavoidable"]["count"], labels["undecided"]["count"]) == (2, 1, 1)
    assert out["oracle"]["held_safety"]["count"] == 2
    assert out["oracle"]["min_distance_m"] == {"min": 0.1, "median": 0.30000000000000004}
    assert out["oracle"]["witnesses"]["preview-1s"] == {"tried": 3, "held": 2, "chosen": 2}
    assert out["oracle"]["witnesses"]["oracle-2s"] == {"tried": 1, "held": 0, "chosen": 0}
    assert out["oracle"]["draws"]["total"] == 7 and out["oracle"]["draws"]["rejected"] == 3
    a = out["methods"]["a"]["obstacle_violations"]
    b = out["methods"]["b"]["obstacle_violations"]
    assert [a[k]["count"] for k in ("avoidable", "unavoidable", "undecided")] == [1, 1, 1] and a["avoidable"][
        "runs"
    ] == 4
    assert [b[k]["count"] for k in ("avoidable", "unavoidable", "undecided")] == [1, 1, 1]
    assert a["episodes"] == {"avoidable": 2, "unavoidable": 2, "undecided": 2}
    assert a["avoidable_given_held"] == rate(1, 2)
    pair = out["paired_avoidable"]["a vs b"]  # seeds 0 and 2, the avoidable runs
    assert (pair["runs"], pair["a_only"], pair["b_only"]) == (2, 1, 1)
    text = "\n".join(
        report_lines({"oracle": out["oracle"], "methods": out["methods"], "paired_avoidable": out["paired_avoidable"]})
    )
    assert "avoidable 2/4 = 50.0 %" in text and "| a | 1/4 = 25.0 %" in text and "rejection rate 42.9 %" in text
    assert "| preview-1s | 3 | 2 | 2 |" in text and "| a vs b | 2 | 1 / 1 |" in text


def test_no_oracle_no_aggregate(tmp_path):
    _write_run(tmp_path, 0, None, {"a": {"obstacles": {"violations": 1}}})
    assert oracle_sweep_summary(tmp_path) is None
    assert report_lines({"methods": {}}) == []


def test_an_avoidable_family_without_a_rejection_says_so(tmp_path):
    """Every draw 0 avoidable: the report still states the family and its 0 % rejection rate."""
    w = {"preview-1s": {"held": True}}
    for seed in range(2):
        entry = {"label": "avoidable", "witness": "preview-1s", "min_distance_m": 0.5, "witnesses": w}
        _write_run(tmp_path, seed, entry | {"draws": 1, "avoidable_draw_found": True}, {"a": {}})
    out = oracle_sweep_summary(tmp_path)
    assert out["oracle"]["draws"]["avoidable_family"] is True
    text = "\n".join(report_lines({"oracle": out["oracle"], "methods": out["methods"], "paired_avoidable": {}}))
    assert "avoidable family: 2 draws for 2 runs, rejection rate 0.0 %" in text
    # Not a family: no such line.
    for run in (tmp_path / "runs").iterdir():
        run.rename(tmp_path / f"old-{run.name}")
    for seed in range(2):
        entry = {"label": "avoidable", "witness": "preview-1s", "min_distance_m": 0.5, "witnesses": w}
        _write_run(tmp_path, seed, entry, {"a": {}})
    out = oracle_sweep_summary(tmp_path)
    assert "avoidable family" not in "\n".join(report_lines({"oracle": out["oracle"], "methods": {}}))

"""Smoke tests of the solver benchmark runner (compare.bench.solvers) and ``tpik-compare bench``."""

from __future__ import annotations

import json

import pytest
from typer.testing import CliRunner

from compare.bench.solver_cases import active_set_tasks, case2_states
from compare.bench.solvers import candidate_hierarchy, run_solver_bench
from compare.cli import app


def test_runner_times_each_case_and_skips_unknown_methods(capsys):
    rows = run_solver_bench(["tpik", "no-such-method"], repeats=3)
    assert "skipping method 'no-such-method'" in capsys.readouterr().out
    assert [(r.name, r.case) for r in rows] == [
        (name, case)
        for case in ("case2-active0", "case2-active1", "case2-active3")
        for name in ("mink-native", "tpik")  # mink alone, the reference of "× mink", in every case
    ]
    for row in rows:
        assert row.samples == 3 and 0 < row.median_us <= row.p95_us
    tpik = [r for r in rows if r.name == "tpik"]
    native = {r.case: r.median_us for r in rows if r.name == "mink-native"}
    for row in tpik:
        assert {"core_us", "build_us", "rows_us", "rest_us", "active", "modes_evaluated"} <= set(row.extra)
        assert row.extra["ratio_to_mink"] == pytest.approx(row.median_us / native[row.case])
    assert tpik[0].extra["active"] == 0


@pytest.mark.parametrize("k", [0, 1, 4, 9, 12])
def test_candidate_hierarchy_has_exactly_k_candidates(jaco, k):
    q = case2_states(jaco)[0].q
    h = candidate_hierarchy(jaco, q, k)
    assert len(h.set_tasks) == 12
    assert len(active_set_tasks(h, jaco, q)) == k
    kin = jaco.kinematics(q)
    for task in h.set_tasks:  # candidates sit in the activation band, never past safety
        assert task.margins(task.compute_value_and_jacobian(kin)[0])[0] > 0.0


def test_bench_writes_the_design_json(tmp_path):
    out = tmp_path / "bench.json"
    argv = ["bench", "--only", "solvers", "--methods", "tpik", "--repeats", "10", "--max-candidates", "1"]
    result = CliRunner().invoke(app, [*argv, "--json", str(out)])
    assert result.exit_code == 0, result.output
    data = json.loads(out.read_text())
    assert set(data) == {"versions", "command", "robot", "results"}
    cases = {(r["name"], r["case"]) for r in data["results"]}
    assert ("tpik", "case2-active3") in cases and ("tpik-exhaustive", "tpik-candidates-1") in cases
    assert ("mink-native", "case2-active3") in cases and ("mink-native", "tpik-candidates-1") in cases
    assert all({"name", "case", "median_us", "p95_us"} <= set(r) for r in data["results"])


def test_bench_rejects_bad_arguments():
    assert CliRunner().invoke(app, ["bench", "--repeats", "0"]).exit_code == 2

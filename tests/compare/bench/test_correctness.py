"""Timing vs correctness bench: the lexicographic comparison, the accounting, and its acceptance."""

from __future__ import annotations

import csv
import json
import math

import numpy as np
import pytest
from click.testing import Result
from typer.testing import CliRunner

from compare.bench.correctness import (
    HQP_BACKENDS,
    QPBENCHMARK_TOLERANCE,
    StepRecord,
    compare_levels,
    judge_step,
    run_correctness_bench,
    summarize,
    wilson,
)
from compare.bench.qp_reference import load_reference
from compare.bench.qp_states import apply_qp_state
from compare.bench.solver_cases import case2_hierarchy
from compare.cli import app
from qp_baseline.hqp import available_qp_solvers
from tpik.step_result import SolveStatus, StepResult


def _bench(*args: str) -> Result:
    """``tpik-compare bench ARGS``."""
    return CliRunner().invoke(app, ["bench", *args])


AVAILABLE = [m for m in HQP_BACKENDS if m.removeprefix("hqp-") in available_qp_solvers()]


@pytest.fixture(scope="module")
def reference():
    return load_reference()


def test_compare_levels_is_lexicographic_with_tolerance():
    ref = np.array([0.0, 1.0, 4.0])  # ρ = 0, 1, 2
    assert compare_levels(ref.copy(), ref).verdict == "match"
    worse_first = compare_levels(np.array([1e-6, 0.5, 1.0]), ref, tol=1e-5)  # ρ₀ = 1e-3 lost: wrong
    assert worse_first.verdict == "worse" and worse_first.level == 0
    traded = compare_levels(np.array([(5e-6) ** 2, 1.0, 1.0]), ref, tol=1e-5)  # within tol above, won below
    assert traded.verdict == "better" and traded.level == 2 and traded.correct
    lost_lower = compare_levels(np.array([0.0, 1.0, 4.1]), ref, tol=1e-5)
    assert lost_lower.verdict == "worse" and lost_lower.level == 2
    assert lost_lower.worst == pytest.approx((math.sqrt(4.1) - 2.0) / 3.0)


def _record(**kw: object) -> StepRecord:
    base = dict(
        method="hqp-x",
        state="random-0001",
        state_set="random",
        status="ok",
        verdict="match",
        level=None,
        worst_error=0.0,
        flagged=False,
        levels_dropped=0,
        levels_uncertified=0,
        qp_calls=1,
        retries=0,
        primal_residual=1e-9,
        dual_residual=1e-9,
        duality_gap=1e-9,
        time_us=100.0,
    )
    base.update(kw)
    return StepRecord(**base)  # type: ignore[arg-type]


def test_summary_counts_silent_flagged_and_false_flags():
    records = [
        _record(state="a"),
        _record(state="b", verdict="worse", level=2, worst_error=0.1),  # silent
        _record(state="c", verdict="worse", level=1, worst_error=0.2, flagged=True, levels_dropped=2),
        _record(state="d", flagged=True, levels_uncertified=1),  # correct but flagged
        _record(state="e", verdict="better", level=3, worst_error=-1e-3, time_us=300.0),
    ]
    (s,) = summarize(records)
    assert (s.count, s.correct, s.silent, s.flagged, s.false_flags) == (5, 3, 1, 2, 1)
    assert s.levels_dropped == 2 and s.levels_uncertified == 1 and s.worst_level_error == pytest.approx(0.2)
    assert s.success_rate["rate"] == pytest.approx(0.6)
    lo, hi = s.success_rate["ci95"]
    assert (lo, hi) == pytest.approx(wilson(3, 5)) and lo < 0.6 < hi
    assert s.time_us["median"] == pytest.approx(100.0)


def test_qpbenchmarks_criterion_is_reported_beside_the_lexicographic_verdict():
    records = [
        _record(state="a"),  # correct, residuals 1e-9: qpbenchmark-solved at 1e-6
        _record(state="b", dual_residual=3e-4),  # correct, but a dual residual above tolerance
        _record(state="c", duality_gap=math.inf),  # infinite gap: the worst gap is inf
        _record(state="d", verdict="worse", level=1, worst_error=0.1),  # wrong, residuals small
        _record(state="e", qp_calls=0, primal_residual=math.nan, dual_residual=math.nan, duality_gap=math.nan),
    ]
    (s,) = summarize(records)
    assert s.correct == 4
    assert s.qpbenchmark_success["runs"] == 4 and s.qpbenchmark_success["count"] == 2  # "e" sent no QP
    assert s.qpbenchmark_tolerance == QPBENCHMARK_TOLERANCE == 1e-6
    assert s.dual_residual["max"] == pytest.approx(3e-4) and s.duality_gap["max"] == math.inf
    assert s.duality_gap["non_finite"] == 1 and s.duality_gap["median"] == pytest.approx(1e-9)
    assert not records[4].qpbenchmark_solved()


def test_a_dropped_level_is_a_flag_and_an_unflagged_wrong_answer_is_silent(reference, jaco):
    entry = reference[10]
    hierarchy = case2_hierarchy(jaco)
    apply_qp_state(hierarchy, entry.state)
    zero = StepResult(np.zeros(jaco.nq), SolveStatus.DEGRADED, extras={"levels_dropped": 1})
    rec = judge_step("hqp-fake", entry, zero, hierarchy, jaco)
    moving = np.abs(entry.qdot).max() > 1e-3
    assert rec.flagged and (not moving or not rec.correct) and not rec.silent
    quiet = judge_step("hqp-fake", entry, StepResult(np.zeros(jaco.nq)), hierarchy, jaco)
    assert quiet.silent == (not quiet.correct)
    exact = judge_step("hqp-fake", entry, StepResult(entry.qdot.copy()), hierarchy, jaco)
    assert exact.verdict == "match" and not exact.flagged


@pytest.mark.parametrize("method", AVAILABLE)
def test_no_backend_is_silently_wrong_on_the_case2_states_and_a_random_sample(reference, method):
    """Acceptance, short form: every step matches the reference or reports itself."""
    entries = reference[:3] + reference[3::20]
    records = run_correctness_bench([method], entries, rounds=1)
    assert len(records) == len(entries)
    silent = [(r.state, r.level, r.worst_error, r.message) for r in records if r.silent]
    assert not silent
    assert sum(r.correct for r in records) >= len(records) - 2  # and nearly all are right, not just flagged


@pytest.mark.slow
def test_acceptance_no_backend_is_silently_wrong_on_all_reference_states(reference):
    """Acceptance: on ≥ 200 random case-2 states (and the 3 case-2 states) every backend
    matches the reference cascade or reports DEGRADED/FAILED for that step."""
    records = run_correctness_bench(AVAILABLE, reference, rounds=1)
    for s in summarize(records):
        assert s.silent == 0, s
        assert s.count >= (200 if s.states == "random" else 3)


def test_bench_cli_writes_the_correctness_section_csv_and_plot(tmp_path):
    out = tmp_path / "bench.json"
    result = _bench(
        "--only",
        "correctness",
        "--backends",
        "hqp-daqp",
        "--rounds",
        "1",
        "--json",
        str(out),
        "--csv",
        str(tmp_path / "steps.csv"),
        "--plot",
        str(tmp_path / "tvc.png"),
    )
    assert result.exit_code == 0, result.output
    payload = json.loads(out.read_text())
    assert {"versions", "command", "results", "correctness"} <= set(payload)  # docs/design.md §7 keys kept
    corr = payload["correctness"]
    assert corr["reference"]["fingerprint"] and corr["tolerance"] > 0
    by_set = {s["states"]: s for s in corr["summaries"]}
    assert by_set["case2"]["count"] == 3 and by_set["random"]["count"] >= 200
    assert by_set["random"]["silent"] == 0 and by_set["random"]["name"] == "hqp-daqp"
    assert set(by_set["random"]["success_rate"]) == {"count", "runs", "rate", "ci95"}
    assert set(by_set["random"]["qpbenchmark_success"]) == {"count", "runs", "rate", "ci95"}
    assert by_set["random"]["qpbenchmark_tolerance"] == QPBENCHMARK_TOLERANCE
    with open(tmp_path / "steps.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == by_set["case2"]["count"] + by_set["random"]["count"]
    assert {
        "problem",
        "solver",
        "settings",
        "runtime",
        "found",
        "primal_residual",
        "dual_residual",
        "duality_gap",
        "qpbenchmark_solved",
        "verdict",
    } <= set(rows[0])
    assert (tmp_path / "tvc.png").stat().st_size > 10_000


@pytest.mark.parametrize("argv", [["--rounds", "0"], ["--backends", "mink"], ["--export-method", "mink"]])
def test_bench_cli_rejects_bad_correctness_arguments(argv):
    result = _bench("--only", "correctness", *argv)
    assert result.exit_code == 2 and result.stderr.strip()

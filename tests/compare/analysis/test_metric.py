"""The metric registry: one declaration reaches the summary, the sweep rows and aggregates, and the tables."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pandas as pd
import pytest
from rich.console import Console

from compare.analysis.metric import Column, Metric, MetricsError, RunSteps, SweepRuns
from compare.analysis.metrics import (
    BUILTIN_METRICS,
    compute_summary,
    register_metric,
    registered_metrics,
    unregister_metric,
)
from compare.analysis.report import summary_table
from compare.analysis.results import flatten_method, summarize_sweep_rows
from tests.compare.analysis.test_metrics import make_meta, make_steps


def _largest_speed(run: RunSteps) -> float:
    """Largest |q̇_1| [rad/s]: a metric these tests add."""
    return float(np.nanmax(np.abs(run.column("qdot_1"))))


@pytest.fixture
def speed_metric() -> Iterator[Metric]:
    metric = register_metric(Metric("qdot_1_max", "rad/s", _largest_speed, aggregate=("max",), label="q̇₁ max"))
    yield metric
    unregister_metric(metric.name)


def test_the_builtins_are_registered_first_in_the_order_of_the_summary():
    assert registered_metrics()[: len(BUILTIN_METRICS)] == BUILTIN_METRICS
    summary = compute_summary(make_steps(), make_meta())
    computed = [m.name for m in BUILTIN_METRICS if m.compute is not None]
    assert list(summary) == computed


def test_a_registered_metric_reaches_summary_row_aggregate_and_run_table(speed_metric):
    steps = make_steps()
    steps["qdot_1"] = np.linspace(0.0, 0.4, len(steps))
    summary = compute_summary(steps, make_meta())
    assert summary["qdot_1_max"] == pytest.approx(0.4)
    row = flatten_method(summary)
    assert row["qdot_1_max"] == pytest.approx(0.4)
    runs = pd.DataFrame([{"method": "tpik", "error": None, **row}, {"method": "tpik", "error": None, **row}])
    runs.loc[1, "qdot_1_max"] = 0.7
    assert summarize_sweep_rows(runs)["tpik"]["qdot_1_max"] == {"max": pytest.approx(0.7)}
    console = Console(width=250, record=True)
    console.print(summary_table({"scenario": "s", "seed": 0, "methods": {"tpik": summary}}))
    text = console.export_text()
    assert "q̇₁ max [rad/s]" in text and text.splitlines()[4].rstrip(" │").endswith("0.4")
    assert [c.header for c in speed_metric.sweep_table([])] == ["q̇₁ max [rad/s], max of runs"]


def test_after_unregistering_a_metric_is_computed_no_more(speed_metric):
    unregister_metric(speed_metric.name)
    assert "qdot_1_max" not in compute_summary(make_steps(), make_meta())


def test_a_name_taken_is_refused_unless_replaced(speed_metric):
    with pytest.raises(MetricsError, match="'qdot_1_max' is already registered"):
        register_metric(Metric("qdot_1_max", "rad/s", _largest_speed))
    replacement = Metric("qdot_1_max", "rad/s", lambda run: 1.0)
    assert register_metric(replacement, replace=True) is replacement
    assert compute_summary(make_steps(), make_meta())["qdot_1_max"] == 1.0


def test_an_unknown_statistic_or_a_nameless_metric_is_refused_at_declaration():
    with pytest.raises(MetricsError, match=r"unknown statistic\(s\) mode"):
        Metric("x", "m", None, aggregate=("median", "mode"))  # type: ignore[arg-type]
    with pytest.raises(MetricsError, match="needs a name"):
        Metric("", "m", None)


def test_a_metric_without_compute_is_only_read_from_the_summary():
    metric = Metric("written_by_the_run", "", None, aggregate=("sum",))
    assert metric.columns({"written_by_the_run": 3}) == {"written_by_the_run": 3}
    rows = pd.DataFrame({"written_by_the_run": [3, None, 4]})
    assert metric.aggregates(SweepRuns(rows)) == {"written_by_the_run": {"sum": 7.0}}
    assert metric.run_table([]) == [] and metric.sweep_table([]) == []


def test_sweep_statistics_use_the_finite_values_only():
    runs = SweepRuns(pd.DataFrame({"x": [1.0, np.nan, 3.0, "n/a", np.inf], "flag": [0, 2, None, 1, 0]}))
    assert runs.stat("x", "median") == 2.0 and runs.stat("x", "sum") == 4.0 and runs.stat("x", "p95") == 2.9
    assert runs.stat("absent", "max") is None and runs.total("absent") == 0
    assert runs.share(runs.positive("flag"))["count"] == 2 and runs.share(runs.positive("flag"))["runs"] == 5
    with pytest.raises(MetricsError, match="unknown statistic 'mode'"):
        runs.stat("x", "mode")  # type: ignore[arg-type]


def test_what_several_metrics_share_is_computed_once_per_run():
    calls = []

    def mask(run: RunSteps) -> np.ndarray:
        calls.append(1)
        return run.flag("fallback")

    run = RunSteps(make_steps(), make_meta())
    assert run.shared(mask) is run.shared(mask)
    assert len(calls) == 1


def test_explicit_columns_replace_those_of_the_label():
    column = Column("two cells", lambda e: "a", section="cost")
    metric = Metric("x", "m", None, label="x", run_columns=(column,), sweep_columns=lambda entries: [column] * 2)
    assert metric.run_table([]) == [column] and metric.sweep_table([{}]) == [column, column]


def test_a_flag_is_the_same_from_a_bool_column_and_from_a_column_with_missing_values():
    steps = make_steps()
    values = np.arange(len(steps)) % 3 == 0
    steps["fallback"] = values
    nullable = steps.copy()
    nullable["fallback"] = pd.array(np.where(values, True, None), dtype="object")  # a missing value is False
    got = RunSteps(steps, make_meta()).flag("fallback")
    assert got.dtype == bool and np.array_equal(got, values)
    assert np.array_equal(RunSteps(nullable, make_meta()).flag("fallback"), values)
    got[:] = False  # a copy: the table is untouched
    assert np.array_equal(steps["fallback"].to_numpy(), values)

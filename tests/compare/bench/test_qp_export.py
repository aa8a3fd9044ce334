"""Level QPs exported as a qpbenchmark test set read back as qpbenchmark reads them, and solve to the reference."""

from __future__ import annotations

import ast
import csv

import numpy as np
import pandas as pd
import pytest
import qpsolvers
from click.testing import Result
from typer.testing import CliRunner

from compare.bench.qp_export import PARQUET_KEYS, collect_bench_qps, export_test_set
from compare.bench.qp_reference import load_reference
from compare.cli import app


def _bench(*args: str) -> Result:
    """``tpik-compare bench ARGS``."""
    return CliRunner().invoke(app, ["bench", *args])


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    entries = load_reference()[:6]  # the case-2 states and three random ones
    problems = collect_bench_qps("hqp-piqp", entries)
    out = export_test_set(problems, tmp_path_factory.mktemp("qps"), "test")
    return problems, out


def test_every_backend_level_qp_is_written_once_by_name(exported):
    problems, out = exported
    names = [p.name for p in problems]
    assert len(names) == len(set(names)) >= 4
    assert sorted(f.stem for f in (out / "data").glob("*.npz")) == sorted(names)
    assert all(p.name.startswith(p.state) and p.level_name in p.name for p in problems)


def test_npz_files_load_as_qpsolvers_problems_equal_to_the_level_qps(exported):
    problems, out = exported
    for item in problems:
        loaded = qpsolvers.Problem.load(str(out / "data" / f"{item.name}.npz"))  # qpbenchmark's Problem.load
        qp = item.qp
        for key in ("P", "q", "G", "h", "lb", "ub"):
            np.testing.assert_array_equal(getattr(loaded, key), getattr(qp, key), err_msg=f"{item.name}: {key}")
        assert loaded.A is None and loaded.b is None


def test_parquet_reads_back_as_qpbenchmark_parquet_test_sets_do(exported):
    problems, out = exported
    df = pd.read_parquet(out / "problems.parquet", engine="pyarrow")
    assert list(df.columns) == list(PARQUET_KEYS)
    by_name = {p.name: p.qp for p in problems}
    for _, row in df.iterrows():
        n = row["q"].size
        qp = by_name[row["name"]]
        # qpbenchmark's ParquetTestSet: matrices are stored flat and reshaped to (size // n, n).
        np.testing.assert_array_equal(row["P"].reshape(-1, n), qp.P)
        np.testing.assert_array_equal(row["G"].reshape(-1, n), qp.G)
        np.testing.assert_array_equal(row["h"], qp.h)
        assert row["A"] is None and row["b"] is None


def test_solutions_give_the_reference_objective_an_independent_solver_reaches(exported):
    problems, out = exported
    with open(out / "solutions.csv", newline="") as fh:
        rows = {r["name"]: r for r in csv.DictReader(fh)}
    assert set(rows) == {p.name for p in problems}
    for item in problems:
        row = rows[item.name]
        problem = qpsolvers.Problem.load(str(out / "data" / f"{item.name}.npz"))
        exact = qpsolvers.solve_problem(problem, solver="quadprog")  # dual active set: exact here
        f_exact = item.qp.objective(exact.x)
        assert float(row["reference_objective"]) == pytest.approx(f_exact, abs=1e-9, rel=1e-9)
        if row["cascade_certified"] == "True":
            assert float(row["cascade_objective"]) == pytest.approx(f_exact, abs=1e-6, rel=1e-6)


def test_the_test_set_script_is_a_qpbenchmark_test_set(exported):
    _, out = exported
    tree = ast.parse((out / "hqp_cascade.py").read_text())
    classes = [n for n in tree.body if isinstance(n, ast.ClassDef)]
    assert [c.name for c in classes] == ["HqpCascade"]
    assert ast.unparse(classes[0].bases[0]) == "qpbenchmark.TestSet"
    methods = {f.name for f in classes[0].body if isinstance(f, ast.FunctionDef)}
    assert {"description", "title", "sparse_only", "__iter__"} <= methods
    assert "Problem.load" in (out / "hqp_cascade.py").read_text()


@pytest.mark.slow
def test_bench_cli_exports_the_reference_states(tmp_path):
    out = tmp_path / "set"
    result = _bench("--only", "correctness", "--backends", "hqp-daqp", "--rounds", "1", "--export-qps", str(out))
    assert result.exit_code == 0, result.output
    files = list((out / "data").glob("*.npz"))
    assert len(files) > 200  # at least one level QP per reference state
    assert (out / "README.md").read_text().startswith("# HQP cascade test set")

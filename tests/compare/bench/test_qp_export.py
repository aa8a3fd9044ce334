"""The qpbenchmark export: hard, de-correlated level QPs, read back as qpbenchmark reads them.

qpbenchmark itself is not a dependency: its Parquet reader is replaced here by a stand-in that reads
``problems.parquet`` as qpbenchmark 2.7.1's ``ParquetTestSet`` does, so the script's class, the
Parquet layout, the names, the references and the selection are tested with pandas and pyarrow
alone. One test runs the real qpbenchmark when it is installed.
"""

from __future__ import annotations

import csv
import importlib.util
import sys
import types
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import qpsolvers
from click.testing import Result
from typer.testing import CliRunner

from compare.bench.qp_export import (
    FAMILY,
    HIGH_ACCURACY_SETTINGS,
    NAME_PATTERN,
    PARQUET_KEYS,
    RUN_COMMAND,
    Candidate,
    NamedLevelQp,
    Reference,
    collect_bench_qps,
    export_test_set,
    qpbenchmark_failures,
    select_problems,
)
from compare.bench.qp_reference import load_reference
from compare.cli import app
from qp_baseline.backends import SUPPORTED_SOLVERS


def _bench(*args: str) -> Result:
    """``tpik-compare bench ARGS``."""
    return CliRunner().invoke(app, ["bench", *args])


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    entries = load_reference()[:8]  # the case-2 states and five random ones
    candidates = collect_bench_qps("hqp-piqp", entries)
    export = export_test_set(candidates, tmp_path_factory.mktemp("qps"), "test", min_failing=0)
    return candidates, export


def _read_like_qpbenchmark(path: Path):
    """Rows of ``problems.parquet`` as qpbenchmark 2.7.1's ``ParquetTestSet.__iter__`` makes them."""
    df = pd.read_parquet(path, engine="pyarrow")
    for _, row in df.iterrows():
        n = row["q"].size
        data = {}
        for key in PARQUET_KEYS:
            value = row[key]
            if isinstance(value, np.ndarray):
                value = value.copy()
                if key in ("P", "G", "A"):
                    value = value.reshape((value.size // n, n))
            data[key] = value
        yield data


def _fake_qpbenchmark(monkeypatch) -> None:
    """Stand-in ``qpbenchmark`` (``ParquetTestSet`` reading as 2.7.1 does, ``benchmark.main``)."""

    class ParquetTestSet:
        def __init__(self, path):
            self.path = Path(path)
            assert isinstance(self.sparse_only, bool) and self.title and self.description

        def __iter__(self):
            for data in _read_like_qpbenchmark(self.path):
                name = data.pop("name")
                problem = qpsolvers.Problem(**data)
                problem.name = name
                yield problem

    package = types.ModuleType("qpbenchmark")
    package.ParquetTestSet = ParquetTestSet
    benchmark = types.ModuleType("qpbenchmark.benchmark")
    benchmark.main = lambda **kwargs: None
    package.benchmark = benchmark
    monkeypatch.setitem(sys.modules, "qpbenchmark", package)
    monkeypatch.setitem(sys.modules, "qpbenchmark.benchmark", benchmark)


def _load_script(path: Path):
    spec = importlib.util.spec_from_file_location("hqp_cascade", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_one_problem_per_state_named_as_the_free_for_all_set_names_them(exported):
    candidates, export = exported
    names = [c.exported_as for c in export.problems]
    assert names == [f"{FAMILY}{i}" for i in range(len(names))] and names
    assert all(NAME_PATTERN.fullmatch(n) for n in names)
    states = [c.item.state for c in export.problems]
    assert len(states) == len(set(states)) == len({c.state for c in candidates if c.level_name != "min_norm"})
    assert all(c.item.level_name != "min_norm" for c in export.candidates)  # only task levels are candidates
    for kept in export.problems:  # the hardest of its state
        rivals = [c for c in export.candidates if c.item.state == kept.item.state]
        assert len(kept.failing) == max(len(c.failing) for c in rivals)
    assert sorted(f.stem for f in (export.out_dir / "data").glob("*.npz")) == sorted(names)


def test_the_script_class_reads_the_parquet_file_as_the_problems(exported, monkeypatch):
    _, export = exported
    _fake_qpbenchmark(monkeypatch)
    module = _load_script(export.out_dir / "hqp_cascade.py")
    test_set = module.HqpCascade()  # qpbenchmark instantiates the class named after the file, no argument
    assert test_set.sparse_only is False
    read = {p.name: p for p in test_set}
    assert list(read) == [c.exported_as for c in export.problems]
    for c in export.problems:
        qp, got = c.item.qp, read[c.exported_as]
        for key in ("P", "q", "G", "h", "lb", "ub"):
            np.testing.assert_array_equal(getattr(got, key), getattr(qp, key), err_msg=f"{c.exported_as}: {key}")
        assert got.A is None and got.b is None
        npz = qpsolvers.Problem.load(str(export.out_dir / "data" / f"{c.exported_as}.npz"))
        np.testing.assert_array_equal(npz.P, got.P)


def test_parquet_columns_are_qpbenchmarks(exported):
    _, export = exported
    df = pd.read_parquet(export.out_dir / "problems.parquet", engine="pyarrow")
    assert tuple(df.columns) == PARQUET_KEYS


def test_every_problem_has_a_certified_reference_cost_an_exact_solver_reaches(exported):
    _, export = exported
    with open(export.out_dir / "solutions.csv", newline="") as fh:
        rows = {r["name"]: r for r in csv.DictReader(fh)}
    assert list(rows) == [c.exported_as for c in export.problems]
    for c in export.problems:
        row = rows[c.exported_as]
        assert np.isfinite(float(row["reference_objective"]))
        assert float(row["reference_primal_residual"]) <= 1e-10
        exact = qpsolvers.solve_problem(c.item.qp.problem(), solver="quadprog")  # dual active set: exact here
        f_exact = c.item.qp.objective(exact.x)
        assert float(row["reference_objective"]) == pytest.approx(f_exact, abs=1e-9, rel=1e-9)
        assert row["failing_solvers"] == " ".join(c.failing)
    with open(export.out_dir / "candidates.csv", newline="") as fh:
        listed = list(csv.DictReader(fh))
    assert len(listed) == len(export.candidates)
    assert sorted(r["exported_as"] for r in listed if r["exported_as"]) == sorted(rows)


def test_script_and_readme_carry_the_licence_and_the_noninteractive_command(exported):
    _, export = exported
    script = (export.out_dir / "hqp_cascade.py").read_text()
    readme = (export.out_dir / "README.md").read_text()
    assert "# SPDX-License-Identifier: Apache-2.0" in script.splitlines()[:3]
    assert "SPDX-License-Identifier: Apache-2.0" in readme.splitlines()[0]
    assert "class HqpCascade(ParquetTestSet):" in script
    assert "--results-path" in RUN_COMMAND and "--author" in RUN_COMMAND and "--settings" not in RUN_COMMAND
    assert RUN_COMMAND in readme and RUN_COMMAND in script
    assert "1e-9" in readme and "Regularisation" in readme


def _candidate(state: str, level: int, failing: tuple[str, ...], active: int = 0) -> Candidate:
    item = NamedLevelQp(f"{state}_L{level}", state, f"level{level}", "hqp-x", types.SimpleNamespace(level=level))
    ref = Reference(np.zeros(1), 0.0, "reference", 0.0, 0.0, 0.0, active)
    return Candidate(item, ref, {s: s in failing for s in ("a", "b", "c")})


def test_selection_keeps_the_hardest_problem_of_each_state_above_the_threshold():
    cands = [
        _candidate("s0", 0, ("a",)),
        _candidate("s0", 1, ("a", "b")),  # most failing solvers
        _candidate("s1", 0, ("a", "b"), active=1),
        _candidate("s1", 2, ("b", "c"), active=3),  # tie on failures: more active constraints
        _candidate("s2", 0, ("a",)),  # below the threshold
        _candidate("s3", 1, ("a", "b")),
        _candidate("s3", 2, ("a", "b")),  # full tie: the higher-priority level (1)
    ]
    kept = select_problems(cands, min_failing=2)
    assert [(c.item.state, c.item.qp.level, c.exported_as) for c in kept] == [
        ("s0", 1, "HQPIK0"),
        ("s1", 2, "HQPIK1"),
        ("s3", 1, "HQPIK2"),
    ]


def test_failures_are_judged_with_qpbenchmarks_high_accuracy_settings_of_the_six_backends():
    assert set(HIGH_ACCURACY_SETTINGS) == set(SUPPORTED_SOLVERS)
    easy = qpsolvers.Problem(np.eye(2), np.array([-1.0, -1.0]), np.array([[1.0, 1.0]]), np.array([1.0]))
    failures = qpbenchmark_failures(easy, ["quadprog", "daqp", "piqp"])
    assert failures == {"quadprog": False, "daqp": False, "piqp": False}


@pytest.mark.skipif(importlib.util.find_spec("qpbenchmark") is None, reason="qpbenchmark is not installed")
def test_qpbenchmark_itself_loads_the_set(exported):
    from qpbenchmark.benchmark import load_test_set

    _, export = exported
    test_set = load_test_set(str(export.out_dir / "hqp_cascade.py"))
    assert [p.name for p in test_set] == [c.exported_as for c in export.problems]


@pytest.mark.slow
def test_bench_cli_exports_the_reference_states(tmp_path):
    out = tmp_path / "set"
    result = _bench("--only", "correctness", "--backends", "hqp-daqp", "--rounds", "1", "--export-qps", str(out))
    assert result.exit_code == 0, result.output
    names = sorted(f.stem for f in (out / "data").glob("*.npz"))
    assert len(names) >= 20 and all(NAME_PATTERN.fullmatch(n) for n in names)
    assert (out / "README.md").read_text().splitlines()[1] == "# HQP cascade test set (qpbenchmark)"

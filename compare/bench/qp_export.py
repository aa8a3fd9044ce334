r"""Hard level QPs of the HQP cascade, written as a qpbenchmark test set.

qpbenchmark (github.com/qpsolvers/qpbenchmark) reads a test set as problems in the qpsolvers
format :math:`\min \tfrac12 x^TPx + q^Tx` s.t. :math:`Gx \le h,\ Ax = b,\ lb \le x \le ub`.
:func:`export_test_set` writes, in one directory:

* ``problems.parquet``: the problems in qpbenchmark's Parquet layout (its ``ProblemList``: columns
  ``P, q, G, h, A, b, lb, ub, name``, matrices flattened row-major, reshaped on reading to
  ``(size // n, n)`` with ``n = q.size``);
* ``hqp_cascade.py``: the test set, ``HqpCascade``, a subclass of qpbenchmark's ``ParquetTestSet``
  reading ``problems.parquet`` (Apache-2.0 licence header);
* ``data/<name>.npz``: the same problems one per file (``qpsolvers.Problem.save``), the layout of
  qpbenchmark's free-for-all test set (file stem = problem name);
* ``solutions.csv``: per problem, where it comes from, its reference objective (every problem
  has one) and which solvers fail it;
* ``candidates.csv``: every candidate QP, how hard it is and whether it was kept;
* ``README.md``: what the problems are, how they were chosen, the commands that run them.

Run ``python -m compare.bench.qp_export OUT_DIR [--method hqp-piqp] [--min-failing 2]`` (or
``tpik-compare bench --only correctness --export-qps OUT_DIR``, which also runs the bench).

**Candidates.** Every task-level QP the cascade of one HQP method sends to its backend on the
bench's reference states (:mod:`compare.bench.qp_reference`: three case-2 states and 200 random
ones). The cascade's final min-norm level (posed only by the inexact backends' cascades,
``min_norm_level``) is left out. Each candidate gets a reference solution, certified to
:data:`~qp_baseline.lexicographic.REFERENCE_TOLERANCES` (:func:`reference_solution`); a candidate
without one is left out.

**Hardness** (:func:`qpbenchmark_failures`): the solvers, among the six QP backends the project
installs, that fail qpbenchmark's success criterion at its ``high_accuracy`` settings
(:data:`HIGH_ACCURACY_SETTINGS`): a solution found, and primal residual, dual residual and duality
gap all below 1e-9 (qpsolvers' definitions, which qpbenchmark uses).

**Selection** (:func:`select_problems`): the level QPs of one state share rows and the answer of
the levels above, so they are strongly correlated; the states are independent draws. One problem
per state is taken: the one the most solvers fail (ties: more constraints active at the reference
solution, then the higher-priority level). A state is kept when at least ``min_failing`` solvers
fail its problem (:data:`MIN_FAILING`). Kept problems are named as the free-for-all set names
its problems, a family in capitals and an index: ``HQPIK0``, ``HQPIK1``, ... in state order.

**Regularisation.** Each task level minimises :math:`\|J\dot q - r\|^2 + \|w\|^2 +
\epsilon\|\dot q\|^2` (:mod:`qp_baseline.hqp`, ``regularization`` ε = 1e-9). In the level's
variables :math:`x = [z;\ w]` that is :math:`P = \mathrm{diag}((JZ)^TJZ + \epsilon I,\ I)`: the
directions the level's tasks leave free have curvature ε, so cond(P) ≈ 1e9 whenever a task
level does not fix every joint (every level of these sets). The exported problems keep it: they
are the QPs the cascade poses.
"""

from __future__ import annotations

import csv
import math
import re
import sys
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import qpsolvers

import robots
from compare.arguments import ArgumentParser, output_dir, positive_int
from compare.bench.qp_reference import ReferenceMismatch, load_reference
from compare.bench.qp_states import apply_qp_state
from compare.bench.solver_cases import case2_hierarchy
from compare.methods import available_methods, make_method
from qp_baseline.certificate import certify
from qp_baseline.hqp import HqpSolver
from qp_baseline.level_qp import LevelQp
from qp_baseline.lexicographic import REFERENCE_TOLERANCES, ReferenceSolutionError, solve_level_qp

PARQUET_KEYS = ("P", "q", "G", "h", "A", "b", "lb", "ub", "name")
"""Columns of qpbenchmark's Parquet test sets (``qpbenchmark.ProblemList.KEYS``)."""

FAMILY = "HQPIK"
"""Name prefix of the exported problems (free-for-all style: a family in capitals and an index)."""

NAME_PATTERN = re.compile(rf"{FAMILY}\d+")
"""Every exported problem's name."""

MIN_FAILING = 2
"""Default least number of solvers failing a state's problem for the state to be kept."""

QPBENCHMARK_TOLERANCE = 1e-9
"""qpbenchmark's ``high_accuracy`` tolerance on the primal residual, dual residual and duality gap."""

HIGH_ACCURACY_SETTINGS: Mapping[str, Mapping[str, Any]] = {
    "clarabel": {"tol_feas": 1e-9, "tol_gap_abs": 1e-9, "tol_gap_rel": 0.0},
    "daqp": {"dual_tol": 1e-9, "primal_tol": 1e-9},
    "osqp": {"eps_abs": 1e-9, "eps_rel": 0.0, "time_limit": 10.0},
    "piqp": {
        "eps_abs": 1e-9,
        "eps_rel": 0.0,
        "eps_duality_gap_abs": 1e-9,
        "eps_duality_gap_rel": 0.0,
        "check_duality_gap": True,
    },
    "proxqp": {
        "eps_abs": 1e-9,
        "eps_rel": 0.0,
        "eps_duality_gap_abs": 1e-9,
        "eps_duality_gap_rel": 0.0,
        "check_duality_gap": True,
    },
    "quadprog": {},
}
"""qpbenchmark 2.7.1's ``high_accuracy`` solver settings (``TestSet.define_solver_settings``) of the six backends."""

TEST_SET_FILE = "hqp_cascade.py"
"""The test-set script; qpbenchmark finds its class ``HqpCascade`` from the file name."""

RESULTS_CSV = "results/hqp_cascade.csv"
"""Where the README's command has qpbenchmark write its results (its report goes beside it)."""

QPBENCHMARK_VERSION = "2.7.1"
"""The qpbenchmark version the README's commands were checked with."""

RUN_COMMAND = f"qpbenchmark {TEST_SET_FILE} --results-path {RESULTS_CSV} run --author tpik-compare"
"""qpbenchmark's command for the exported set, run from its directory: every solver and settings group.

``--results-path`` gives the results CSV (``qpbenchmark FILE run`` has none); ``--author`` fills the
report's author field, which ``run`` otherwise asks for on the terminal. ``run --settings NAME``
stops at the report in qpbenchmark 2.7.1 (it expects the ``default`` group), so every group runs.
"""

_TEST_SET_SCRIPT = f'''#!/usr/bin/env python3
# SPDX-License-Identifier: Apache-2.0
# SPDX-FileCopyrightText: the tpik-compare authors
"""HQP cascade test set: hard level QPs of a hierarchical-QP inverse-kinematics cascade (README.md).

Run from this directory (qpbenchmark {QPBENCHMARK_VERSION}):

    {RUN_COMMAND}
"""

import os

from qpbenchmark import ParquetTestSet
from qpbenchmark.benchmark import main

HERE = os.path.dirname(os.path.abspath(__file__))


class HqpCascade(ParquetTestSet):
    """Level QPs of a lexicographic HQP cascade (7-DOF arm; dense, small, ill-conditioned)."""

    @property
    def description(self) -> str:
        return (
            "Hard level QPs of a lexicographic hierarchical-QP inverse-kinematics cascade: "
            "least squares of the level's tasks plus slacks of its set-task rows, "
            "under the rows of the levels above and a joint-velocity box."
        )

    @property
    def title(self) -> str:
        return "HQP cascade test set"

    @property
    def sparse_only(self) -> bool:
        return False

    def __init__(self):
        super().__init__(os.path.join(HERE, "problems.parquet"))


if __name__ == "__main__":
    main(test_set_path=os.path.abspath(__file__), results_path=os.path.join(HERE, "{RESULTS_CSV}"))
'''


@dataclass(frozen=True)
class NamedLevelQp:
    """A level QP posed by a cascade, with where it came from.

    Attributes:
        name: Candidate name, ``<state>_L<level>_<level name>`` (:func:`problem_name`).
        state: State the cascade was solving.
        level_name: Level name (``min_norm`` for the last level).
        method: Method whose cascade posed it.
        qp: The level QP and the cascade's answer.
    """

    name: str
    state: str
    level_name: str
    method: str
    qp: LevelQp


@dataclass(frozen=True)
class Reference:
    """A certified reference solution of one QP.

    Attributes:
        x: The solution.
        objective: ½xᵀPx + qᵀx at ``x``.
        solver: What gave it (``reference``: :func:`qp_baseline.lexicographic.solve_level_qp`;
            else the backend whose answer was certified).
        primal_residual: Its primal residual.
        dual_residual: Its dual residual (certificate's multipliers).
        duality_gap: Its duality gap (same multipliers).
        active: Constraints (rows and bounds) active at ``x`` (within 1e-9).
    """

    x: np.ndarray
    objective: float
    solver: str
    primal_residual: float
    dual_residual: float
    duality_gap: float
    active: int


@dataclass
class Candidate:
    """A candidate QP, judged.

    Attributes:
        item: The level QP.
        reference: Its reference (None: none certified; the candidate is left out).
        failures: Per solver, whether it fails qpbenchmark's high-accuracy criterion.
        exported_as: Its problem name when kept (empty otherwise).
    """

    item: NamedLevelQp
    reference: Reference | None
    failures: dict[str, bool] = field(default_factory=dict)
    exported_as: str = ""

    @property
    def failing(self) -> list[str]:
        """The solvers that fail it, sorted."""
        return sorted(s for s, failed in self.failures.items() if failed)


@dataclass(frozen=True)
class TestSetExport:
    """What :func:`export_test_set` wrote.

    Attributes:
        out_dir: The test-set directory.
        candidates: Every candidate, judged (``exported_as`` set on the kept ones).
        problems: The kept candidates, in name order.
    """

    __test__ = False  # not a pytest class

    out_dir: Path
    candidates: list[Candidate]
    problems: list[Candidate]


def problem_name(state: str, level: int, level_name: str) -> str:
    """Candidate name ``<state>_L<level>_<level name>``."""
    return f"{state}_L{level}_{level_name}"


def _flat(a: np.ndarray | None) -> np.ndarray | None:
    return None if a is None else np.asarray(a, dtype=float).ravel()


def _active(qp: LevelQp, x: np.ndarray, tol: float = 1e-9) -> int:
    rows = int(np.count_nonzero(qp.G @ x >= qp.h - tol)) if qp.h.size else 0
    return rows + int(np.count_nonzero((x <= qp.lb + tol) | (x >= qp.ub - tol)))


def reference_solution(qp: LevelQp) -> Reference | None:
    """The QP's reference: the lexicographic reference's solver, else quadprog's answer, certified.

    Both are accepted only when their optimality conditions hold to
    :data:`~qp_baseline.lexicographic.REFERENCE_TOLERANCES` (:func:`qp_baseline.certificate.certify`).
    quadprog (a dual active-set method, exact here) answers the few QPs whose feasible region is a
    sliver (rows of the levels above relaxed by their optimal slack) that the interior-point first
    passes of the reference leave 1e-8 outside.

    Returns:
        The reference, or None when neither is certified.
    """
    n = qp.q.size
    try:
        x, cert = solve_level_qp(qp.P, qp.q, qp.G, qp.h, np.zeros((0, n)), np.zeros(0), qp.lb, qp.ub)
        solver = "reference"
    except ReferenceSolutionError:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            try:
                sol = qpsolvers.solve_problem(qp.problem(), solver="quadprog")
            except Exception:  # noqa: BLE001 - a backend error only means: no reference
                return None
        if sol.x is None or not np.isfinite(sol.x).all():
            return None
        x = sol.x
        cert = certify(qp.qp, x, y=sol.y, z=sol.z, z_box=sol.z_box, tolerances=REFERENCE_TOLERANCES)
        if not cert.passed:
            return None
        solver = "quadprog"
    return Reference(
        x, qp.objective(x), solver, cert.primal_residual, cert.dual_residual, cert.duality_gap, _active(qp, x)
    )


def qpbenchmark_failures(problem: qpsolvers.Problem, solvers: Sequence[str] | None = None) -> dict[str, bool]:
    """Per solver, whether it fails qpbenchmark's success criterion at ``high_accuracy`` on ``problem``.

    As qpbenchmark 2.7.1 runs a solver: its ``high_accuracy`` settings, CSC matrices for a backend
    that takes only sparse ones, an exception counted as not found; success = found and primal
    residual, dual residual and duality gap each below :data:`QPBENCHMARK_TOLERANCE`.

    Args:
        problem: The QP.
        solvers: Backends to run (default: the six of :data:`HIGH_ACCURACY_SETTINGS` installed).
    """
    names = [s for s in (solvers or HIGH_ACCURACY_SETTINGS) if s in qpsolvers.available_solvers]
    out = {}
    for solver in names:
        given = problem
        if solver in qpsolvers.sparse_solvers and solver not in qpsolvers.dense_solvers:
            given = _sparse(problem)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            try:
                sol = qpsolvers.solve_problem(given, solver=solver, **HIGH_ACCURACY_SETTINGS.get(solver, {}))
            except Exception:  # noqa: BLE001 - qpbenchmark counts any solver exception as not found
                out[solver] = True
                continue
        tol = QPBENCHMARK_TOLERANCE
        ok = bool(sol.found) and all(v < tol for v in (sol.primal_residual(), sol.dual_residual(), sol.duality_gap()))
        out[solver] = not ok
    return out


def _sparse(problem: qpsolvers.Problem) -> qpsolvers.Problem:
    import scipy.sparse as spa

    def csc(m: Any) -> Any:
        return None if m is None else spa.csc_matrix(m)

    p = problem
    return qpsolvers.Problem(csc(p.P), p.q, csc(p.G), p.h, csc(p.A), p.b, p.lb, p.ub)


def judge_candidates(problems: Sequence[NamedLevelQp], solvers: Sequence[str] | None = None) -> list[Candidate]:
    """Reference and qpbenchmark failures of every task-level QP of ``problems`` (min-norm levels left out)."""
    out = []
    for item in problems:
        if item.level_name == "min_norm":
            continue
        ref = reference_solution(item.qp)
        failures = qpbenchmark_failures(item.qp.problem(), solvers) if ref is not None else {}
        out.append(Candidate(item, ref, failures))
    return out


def select_problems(candidates: Sequence[Candidate], min_failing: int = MIN_FAILING) -> list[Candidate]:
    """One problem per state, the hardest, for the states where at least ``min_failing`` solvers fail it.

    Hardest: the most solvers failing; ties to more constraints active at the reference solution,
    then to the higher-priority (lower) level. States keep their first-seen order; the kept ones
    are named ``HQPIK0``, ``HQPIK1``, ... in that order (``exported_as``).

    Returns:
        The kept candidates, in name order.
    """
    by_state: dict[str, list[Candidate]] = {}
    for c in candidates:
        if c.reference is not None:
            by_state.setdefault(c.item.state, []).append(c)
    kept = []
    for group in by_state.values():
        best = max(group, key=lambda c: (len(c.failing), c.reference.active if c.reference else 0, -c.item.qp.level))
        if len(best.failing) >= min_failing:
            kept.append(best)
    for i, c in enumerate(kept):
        c.exported_as = f"{FAMILY}{i}"
    return kept


def export_test_set(
    problems: Sequence[NamedLevelQp],
    out_dir: Path,
    made_with: str,
    min_failing: int = MIN_FAILING,
    solvers: Sequence[str] | None = None,
) -> TestSetExport:
    """Judge ``problems``, keep the hard ones and write them as a qpbenchmark test set (module docstring).

    Args:
        problems: Candidate level QPs (:func:`collect_bench_qps`).
        out_dir: Output directory (created; files of the same names are replaced).
        made_with: The command that made them (for the README).
        min_failing: Least number of solvers failing a state's problem for the state to be kept.
        solvers: Backends that judge hardness (default: the six installed).

    Returns:
        What was written.
    """
    candidates = judge_candidates(problems, solvers)
    kept = select_problems(candidates, min_failing)
    data = out_dir / "data"
    data.mkdir(parents=True, exist_ok=True)
    for stale in data.glob(f"{FAMILY}*.npz"):
        stale.unlink()
    columns: dict[str, list[object]] = {key: [] for key in PARQUET_KEYS}
    for c in kept:
        problem = c.item.qp.problem()
        problem.save(str(data / f"{c.exported_as}.npz"))
        columns["name"].append(c.exported_as)
        for key in PARQUET_KEYS[:-1]:
            columns[key].append(_flat(getattr(problem, key)))
    pd.DataFrame(columns, columns=list(PARQUET_KEYS)).to_parquet(
        out_dir / "problems.parquet", engine="pyarrow", index=False
    )
    _write_csv(out_dir / "solutions.csv", [_solution_row(c) for c in kept])
    _write_csv(out_dir / "candidates.csv", [_candidate_row(c) for c in candidates])
    script = out_dir / TEST_SET_FILE
    script.write_text(_TEST_SET_SCRIPT, encoding="utf-8")
    script.chmod(0o755)
    (out_dir / "results").mkdir(exist_ok=True)  # where qpbenchmark writes its results and report
    export = TestSetExport(out_dir, list(candidates), kept)
    (out_dir / "README.md").write_text(_readme(export, made_with, min_failing), encoding="utf-8")
    return export


def _write_csv(path: Path, rows: list[dict[str, Any]]) -> None:
    with open(path, "w", newline="", encoding="utf-8") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(rows[0]) if rows else ["name"])
        writer.writeheader()
        writer.writerows(rows)


def _solution_row(c: Candidate) -> dict[str, Any]:
    qp, ref = c.item.qp, c.reference
    assert ref is not None  # kept candidates have one
    return {
        "name": c.exported_as,
        "candidate": c.item.name,
        "state": c.item.state,
        "level": qp.level,
        "level_name": c.item.level_name,
        "method": c.item.method,
        "n": qp.q.size,
        "m": qp.h.size,
        "slacks": qp.slacks,
        "reference_objective": ref.objective,
        "reference_x_norm": float(np.linalg.norm(ref.x)),
        "reference_solver": ref.solver,
        "reference_primal_residual": ref.primal_residual,
        "reference_dual_residual": ref.dual_residual,
        "reference_duality_gap": ref.duality_gap,
        "active_constraints": ref.active,
        "failing_solvers": " ".join(c.failing),
        "cascade_objective": math.nan if qp.x is None else qp.objective(qp.x),
        "cascade_certified": bool(qp.certificate is not None and qp.certificate.passed and qp.x is not None),
    }


def _candidate_row(c: Candidate) -> dict[str, Any]:
    ref = c.reference
    return {
        "candidate": c.item.name,
        "state": c.item.state,
        "level": c.item.qp.level,
        "level_name": c.item.level_name,
        "n": c.item.qp.q.size,
        "m": c.item.qp.h.size,
        "reference": ref is not None,
        "active_constraints": ref.active if ref is not None else "",
        "failing": len(c.failing) if ref is not None else "",
        "failing_solvers": " ".join(c.failing),
        "exported_as": c.exported_as,
    }


def _readme(export: TestSetExport, made_with: str, min_failing: int) -> str:
    kept, candidates = export.problems, export.candidates
    methods = sorted({c.item.method for c in candidates}) or ["-"]
    states = len({c.item.state for c in candidates})
    no_ref = sum(c.reference is None for c in candidates)
    solvers = sorted({s for c in candidates for s in c.failures})
    fail_lines = "\n".join(f"| {s} | {sum(c.failures.get(s, False) for c in kept)} / {len(kept)} |" for s in solvers)
    sizes = [c.item.qp.q.size for c in kept]
    rows = [c.item.qp.h.size for c in kept]
    levels = ", ".join(
        f"{name} {count}" for name, count in pd.Series([c.item.level_name for c in kept]).value_counts().items()
    )
    return f"""<!-- SPDX-License-Identifier: Apache-2.0 -->
# HQP cascade test set (qpbenchmark)

{len(kept)} hard level QPs of the hierarchical-QP inverse-kinematics cascade of tpik-compare
(`qp_baseline/hqp.py`), posed by {", ".join(methods)} on the reference states of the bench's
case-2 hierarchy (joint limits > six end-effector walls > obstacle distance of three control
points > end-effector position, a 7-DOF Kinova Jaco²). Made with:

    {made_with}

Licence: Apache-2.0, as tpik-compare (SPDX headers in `{TEST_SET_FILE}` and here).

## Run it

From this directory, in a fresh virtual environment (checked with qpbenchmark {QPBENCHMARK_VERSION}):

    python3 -m venv .venv
    .venv/bin/pip install qpbenchmark=={QPBENCHMARK_VERSION} "qpsolvers[clarabel,daqp,osqp,piqp,proxqp,quadprog]"
    .venv/bin/{RUN_COMMAND}

Results go to `{RESULTS_CSV}`, qpbenchmark's report beside it (`results/hqp_cascade.md`).
`--results-path` is needed (`run` has no default file) and `--author` too (without it `run`
asks for a name on the terminal). `python {TEST_SET_FILE} run --author tpik-compare` does the
same with the results path built in.

## The problems

Level k minimises its tasks' least-squares error plus the squared slacks of its set-task rows
(`0 ≤ w`), under the rows of the levels above (relaxed by their optimal slacks) and the hard
joint-velocity box; earlier equality rows are eliminated in a null-space basis Z. Here
x = [z; w] has {min(sizes, default=0)}–{max(sizes, default=0)} variables, with \
{min(rows, default=0)}–{max(rows, default=0)} inequality rows and a bound on every variable.
Problems by level: {levels or "-"}.

Regularisation: the cascade adds ε‖q̇‖² (ε = 1e-9) to every task level, so
P = diag((JZ)ᵀJZ + εI, I): the directions the level's tasks leave free have curvature 1e-9 and
cond(P) ≈ 1e9, the scale of qpbenchmark's high-accuracy tolerance. The problems keep it: they
are the QPs the cascade poses.

## How they were chosen

1. Candidates: the {len(candidates)} task-level QPs the cascade sent to its backend on {states}
   states (the min-norm level that only inexact backends' cascades pose left out). Each gets a
   reference solution certified to primal residual 1e-10 and duality gap 1e-11 (the project's
   lexicographic reference solver, else quadprog's answer, certified alike); {no_ref} without one
   left out.
2. Hardness: the solvers among {", ".join(solvers) or "-"} that fail
   qpbenchmark's success criterion at its `high_accuracy` settings (found; primal residual,
   dual residual and duality gap each below 1e-9), run as qpbenchmark runs them.
3. De-correlation: the level QPs of one state share rows and the answer of the levels above;
   the states are independent draws. One problem per state: the one the most solvers fail (ties:
   more constraints active at the reference, then the higher-priority level).
4. Kept: the states whose problem at least {min_failing} solvers fail. Names follow qpbenchmark's
   free-for-all set, a family in capitals and an index: `{FAMILY}0` … in state order.

Failures at the export (qpbenchmark's high-accuracy criterion; the selection used them, so the
rates on this set are low by construction):

| solver | fails |
|---|---:|
{fail_lines}

## Files

- `problems.parquet`: the problems in qpbenchmark's Parquet layout, read by `HqpCascade`
  (`{TEST_SET_FILE}`, a `qpbenchmark.ParquetTestSet`);
- `data/<name>.npz`: the same problems one per file (`qpsolvers.Problem.load`), the layout of
  qpbenchmark's free-for-all test set;
- `solutions.csv`: per problem its state and level, the reference objective ½xᵀPx + qᵀx and
  how it was certified, the solvers that fail it, the cascade's own answer;
- `candidates.csv`: every candidate, its failures and the name it was kept under.
"""


def collect_bench_qps(method: str, entries: Sequence[object]) -> list[NamedLevelQp]:
    """Every level QP ``method``'s cascade sends to its backend on the reference states ``entries``.

    Args:
        method: An ``hqp-<backend>`` method name.
        entries: :class:`compare.bench.qp_reference.ReferenceEntry` items.

    Raises:
        ValueError: ``method`` is not an HQP method.
    """
    robot = robots.load(robots.DEFAULT_ROBOT)
    solver = make_method(method, robot)
    if not isinstance(solver, HqpSolver):
        raise ValueError(f"--export-method must be an hqp-<backend> method, got '{method}'")
    hierarchy = case2_hierarchy(robot)
    names = [level.name for level in hierarchy.levels] + ["min_norm"]
    out: list[NamedLevelQp] = []
    for entry in entries:
        state = entry.state  # type: ignore[attr-defined]
        apply_qp_state(hierarchy, state)
        solver.qp_log = []
        solver.solve(hierarchy, robot.kinematics(state.bench.q), state.dt)
        for qp in solver.qp_log:
            level_name = names[min(qp.level, len(names) - 1)]
            name = problem_name(state.name, qp.level, level_name)
            out.append(NamedLevelQp(name, state.name, level_name, method, qp))
    solver.qp_log = None
    return out


def main(argv: list[str] | None = None) -> int:
    """``python -m compare.bench.qp_export OUT_DIR``: export the test set; returns the exit code."""
    hqp = [m for m in available_methods() if m.startswith("hqp-")]
    parser = ArgumentParser(
        prog="python -m compare.bench.qp_export",
        description="Write the hard level QPs an HQP cascade poses on the bench's stored reference states as a\n"
        "qpbenchmark test set (problems.parquet, data/*.npz, solutions.csv, candidates.csv, README.md).\n"
        "Judging every candidate with six QP solvers takes minutes. Also: tpik-compare bench --only\n"
        "correctness --export-qps DIR.",
    )
    parser.add_argument(
        "out_dir", type=output_dir, help="test-set directory (created; files of the same names replaced)"
    )
    parser.add_argument(
        "--method",
        choices=hqp,
        default="hqp-piqp",
        metavar="METHOD",
        help=f"the HQP method whose cascade poses the QPs: {', '.join(hqp)}",
    )
    parser.add_argument(
        "--min-failing",
        type=positive_int,
        metavar="N",
        default=MIN_FAILING,
        help="least number of solvers failing a state's problem for the state to be kept",
    )
    args = parser.parse_args(argv)
    try:
        entries = load_reference()
    except (OSError, ReferenceMismatch) as exc:
        parser.error(f"stored reference: {exc}")
    made_with = (
        f"python -m compare.bench.qp_export {args.out_dir} --method {args.method} --min-failing {args.min_failing}"
    )
    export = export_test_set(collect_bench_qps(args.method, entries), args.out_dir, made_with, args.min_failing)
    print(
        f"wrote {len(export.problems)} hard level QPs (of {len(export.candidates)} candidates) "
        f"posed by {args.method} to {args.out_dir}"
    )
    return 0


__all__ = [
    "FAMILY",
    "HIGH_ACCURACY_SETTINGS",
    "MIN_FAILING",
    "PARQUET_KEYS",
    "RUN_COMMAND",
    "Candidate",
    "NamedLevelQp",
    "Reference",
    "TestSetExport",
    "collect_bench_qps",
    "export_test_set",
    "judge_candidates",
    "main",
    "problem_name",
    "qpbenchmark_failures",
    "reference_solution",
    "select_problems",
]


if __name__ == "__main__":
    sys.exit(main())

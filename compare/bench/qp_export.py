r"""Level QPs of the HQP cascade written as a qpbenchmark test set.

qpbenchmark (github.com/qpsolvers/qpbenchmark) reads a test set as problems in the qpsolvers
format :math:`\min \tfrac12 x^TPx + q^Tx` s.t. :math:`Gx \le h,\ Ax = b,\ lb \le x \le ub`,
either one ``.npz`` file per problem (``qpsolvers.Problem.save``/``load``; the problem's name is
the file name, as in its ``free_for_all`` and ``mpc`` test sets) or one Parquet file whose columns
are ``P, q, G, h, A, b, lb, ub, name`` with matrices flattened row-major (its ``ProblemList`` /
``ParquetTestSet``). :func:`export_test_set` writes both, plus:

* ``solutions.csv``: per problem the reference objective and solution norm (solved to high
  accuracy by :func:`qp_baseline.lexicographic.solve_level_qp`, optimality conditions checked),
  so a solver's cost error can be computed; the cascade's own answer objective and whether it
  was certified;
* ``hqp_cascade.py``: a qpbenchmark ``TestSet`` reading ``data/*.npz``
  (``python hqp_cascade.py run``, results in ``results/``; checked with qpbenchmark 2.7.1);
* ``README.md``: what the problems are and how they were made.

The problems are every level QP a cascade sent to its backend (:attr:`HqpSolver.qp_log
<qp_baseline.hqp.HqpSolver.qp_log>`), named ``<state>_L<level>_<level name>``.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

import robots
from compare.bench.qp_states import apply_qp_state
from compare.bench.solver_cases import case2_hierarchy
from compare.methods import make_method
from qp_baseline.hqp import HqpSolver
from qp_baseline.level_qp import LevelQp
from qp_baseline.lexicographic import ReferenceSolutionError, solve_level_qp

PARQUET_KEYS = ("P", "q", "G", "h", "A", "b", "lb", "ub", "name")
"""Columns of qpbenchmark's Parquet test sets."""

_TEST_SET_SCRIPT = '''#!/usr/bin/env python3
"""HQP cascade level QPs exported by tpik-compare (see README.md). Run: qpbenchmark hqp_cascade.py run"""

import os

import qpbenchmark
from qpbenchmark import Problem
from qpbenchmark.benchmark import main


class HqpCascade(qpbenchmark.TestSet):
    """Level QPs of a hierarchical-QP inverse-kinematics cascade (7-DOF arm, dense, small)."""

    @property
    def description(self) -> str:
        return "Level QPs of a lexicographic HQP cascade (set-based safety tasks with slacks)."

    @property
    def title(self) -> str:
        return "HQP cascade test set"

    @property
    def sparse_only(self) -> bool:
        return False

    def __init__(self):
        super().__init__()
        self.data_dir = os.path.join(os.path.dirname(os.path.abspath(__file__)), "data")

    def __iter__(self):
        for fname in sorted(os.listdir(self.data_dir)):
            if fname.endswith(".npz"):
                yield Problem.load(os.path.join(self.data_dir, fname))


if __name__ == "__main__":
    here = os.path.dirname(os.path.abspath(__file__))
    main(test_set_path=os.path.abspath(__file__), results_path=f"{here}/results/qpbenchmark_results.csv")
'''


@dataclass(frozen=True)
class NamedLevelQp:
    """A level QP with its problem name and where it came from.

    Attributes:
        name: Problem name (file stem).
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


def problem_name(state: str, level: int, level_name: str) -> str:
    """``<state>_L<level>_<level name>``."""
    return f"{state}_L{level}_{level_name}"


def _flat(a: np.ndarray | None) -> np.ndarray | None:
    return None if a is None else np.asarray(a, dtype=float).ravel()


def export_test_set(problems: Sequence[NamedLevelQp], out_dir: Path, made_with: str) -> Path:
    """Write ``problems`` as a qpbenchmark test set in ``out_dir`` (module docstring).

    Args:
        problems: The level QPs.
        out_dir: Output directory (created; existing files of the same names are replaced).
        made_with: The command that made them (for the README).

    Returns:
        ``out_dir``.
    """
    data = out_dir / "data"
    data.mkdir(parents=True, exist_ok=True)
    columns: dict[str, list[object]] = {key: [] for key in PARQUET_KEYS}
    rows = []
    for item in problems:
        qp = item.qp
        problem = qp.problem()
        problem.save(str(data / f"{item.name}.npz"))
        columns["name"].append(item.name)
        for key in PARQUET_KEYS[:-1]:
            columns[key].append(_flat(getattr(problem, key)))
        try:
            x_ref, cert = solve_level_qp(qp.P, qp.q, qp.G, qp.h, np.zeros((0, qp.q.size)), np.zeros(0), qp.lb, qp.ub)
            ref_obj, ref_norm, kkt = qp.objective(x_ref), float(np.linalg.norm(x_ref)), cert.duality_gap
        except ReferenceSolutionError:
            ref_obj = ref_norm = kkt = math.nan
        rows.append(
            {
                "name": item.name,
                "state": item.state,
                "level": qp.level,
                "level_name": item.level_name,
                "method": item.method,
                "n": qp.q.size,
                "m": qp.h.size,
                "slacks": qp.slacks,
                "reference_objective": ref_obj,
                "reference_x_norm": ref_norm,
                "reference_duality_gap": kkt,
                "cascade_objective": math.nan if qp.x is None else qp.objective(qp.x),
                "cascade_certified": bool(qp.certificate is not None and qp.certificate.passed and qp.x is not None),
            }
        )
    pd.DataFrame(columns).to_parquet(out_dir / "problems.parquet", engine="pyarrow", index=False)
    with open(out_dir / "solutions.csv", "w", newline="", encoding="utf-8") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(rows[0]) if rows else ["name"])
        writer.writeheader()
        writer.writerows(rows)
    (out_dir / "hqp_cascade.py").write_text(_TEST_SET_SCRIPT, encoding="utf-8")
    (out_dir / "results").mkdir(exist_ok=True)  # where qpbenchmark writes its results CSV
    (out_dir / "README.md").write_text(_readme(problems, made_with), encoding="utf-8")
    return out_dir


def _readme(problems: Sequence[NamedLevelQp], made_with: str) -> str:
    methods = sorted({p.method for p in problems})
    sizes = [p.qp.q.size for p in problems]
    span = f"{min(sizes, default=0)}–{max(sizes, default=0)}"
    return f"""# HQP cascade test set (qpbenchmark format)

{len(problems)} level QPs of the hierarchical-QP inverse-kinematics cascade of tpik-compare
(`qp_baseline/hqp.py`), posed by {", ".join(methods) or "-"} on the bench's case-2 states
(joint limits > six EE walls > obstacle distance of three control points > EE position, a
7-DOF Kinova Jaco²). Made with:

    {made_with}

Each level minimises its tasks' least-squares error plus the squared slacks of its set-task
rows (`0 ≤ w`), under the relaxed rows of the levels above and the hard joint-velocity box;
earlier equality rows are eliminated in a null-space basis, so x = [z; w] has {span}
variables. The problems are dense, small and ill-conditioned (a 1e-9 regularisation on the
null-space directions), feasible by construction.

- `data/<name>.npz`: one problem per file (`qpsolvers.Problem.load`), name = file stem,
  `<state>_L<level>_<level name>`;
- `problems.parquet`: the same problems in qpbenchmark's Parquet layout (`ParquetTestSet`);
- `solutions.csv`: reference objective (solved to high accuracy, optimality conditions checked)
  for a cost error, and the cascade's own answer;
- `hqp_cascade.py`: the qpbenchmark test set; `qpbenchmark hqp_cascade.py run`.
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

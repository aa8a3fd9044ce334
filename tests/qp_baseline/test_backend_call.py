"""Everything backend-specific comes from the backend's record: no branch or table keyed by its name elsewhere."""

from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as spa

from qp_baseline.backend_call import backend_kwargs, backend_problem
from qp_baseline.backends import BACKENDS
from qp_baseline.exceptions import InvalidSettings
from qp_baseline.qp_problem import DenseProblem
from tests.qp_baseline.helpers import SOLVERS

PACKAGE = Path(__file__).resolve().parents[2] / "qp_baseline"


def _names_used_as_keys_or_in_comparisons(source: str) -> list[str]:
    """Backend names compared to (``solver == "osqp"``, ``in ("osqp", ...)``) or used as dict keys."""
    found = []
    for node in ast.walk(ast.parse(source)):
        constants: list[ast.expr] = []
        if isinstance(node, ast.Compare):
            for side in (node.left, *node.comparators):
                constants.extend(side.elts if isinstance(side, ast.Tuple | ast.List | ast.Set) else [side])
        elif isinstance(node, ast.Dict):
            constants.extend(k for k in node.keys if k is not None)
        found.extend(c.value for c in constants if isinstance(c, ast.Constant) and c.value in BACKENDS)
    return found


@pytest.mark.parametrize("module", sorted(p.name for p in PACKAGE.glob("*.py") if p.name != "backends.py"))
def test_no_module_but_the_record_branches_on_a_backend_name(module):
    assert _names_used_as_keys_or_in_comparisons((PACKAGE / module).read_text(encoding="utf-8")) == []


def test_the_check_finds_such_a_branch():
    assert _names_used_as_keys_or_in_comparisons('if s == "proxqp" or s in ("osqp",):\n    t = {"piqp": 1}') == [
        "proxqp",
        "osqp",
        "piqp",
    ]


@pytest.mark.parametrize("solver", sorted(BACKENDS))
def test_a_backend_gets_the_matrix_format_its_record_names(solver):
    qp = DenseProblem(np.eye(2), np.zeros(2), np.ones((1, 2)), np.ones(1), lb=-np.ones(2), ub=np.ones(2))
    posed = backend_problem(qp, solver)
    assert spa.issparse(posed.P) is BACKENDS[solver].sparse and spa.issparse(posed.G) is BACKENDS[solver].sparse
    assert posed.A is None and posed.b is None
    no_rows = backend_problem(DenseProblem(np.eye(2), np.zeros(2), lb=-np.ones(2), ub=np.ones(2)), solver)
    assert no_rows.G is None and no_rows.h is None


@pytest.mark.parametrize("solver", [s for s in SOLVERS if BACKENDS[s].enum_settings])
def test_an_enum_setting_given_by_name_becomes_its_member(solver):
    for key, members_of in BACKENDS[solver].enum_settings.items():
        name, member = next(iter(members_of().items()))
        assert backend_kwargs(solver, {key: name})[key] is member
        assert backend_kwargs(solver, {key: member})[key] is member
        with pytest.raises(InvalidSettings, match=key):
            backend_kwargs(solver, {key: "NOT_A_MEMBER"})

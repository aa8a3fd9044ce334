"""Functions of ``tpik/`` stay short: at most :data:`MAX_LINES` lines each.

A function is counted from its ``def`` line to its last line, its docstring excluded (the
docstrings carry the math and the paper's equations, which should not be cut short). A compiled
kernel that cannot be split without slowing the control step may be longer if it says why in a
comment containing :data:`EXEMPT_MARK`; the test checks that every exempt function carries one.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[2] / "tpik"
MAX_LINES = 60
EXEMPT_MARK = "length: kernel"
"""A comment with this text inside a function exempts it (with the reason after it)."""


def _functions() -> list[tuple[str, int, bool]]:
    """(``file:function``, length in lines, exempt) of every function and method under tpik/."""
    out = []
    for path in sorted(PACKAGE.rglob("*.py")):
        source = path.read_text(encoding="utf-8")
        lines = source.splitlines()
        for node in ast.walk(ast.parse(source)):
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                assert node.end_lineno is not None
                body = "\n".join(lines[node.lineno - 1 : node.end_lineno])
                length = node.end_lineno - node.lineno + 1
                doc = node.body[0] if node.body else None
                if (
                    isinstance(doc, ast.Expr)
                    and isinstance(doc.value, ast.Constant)
                    and isinstance(doc.value.value, str)
                ):
                    assert doc.end_lineno is not None
                    length -= doc.end_lineno - doc.lineno + 1
                out.append((f"{path.relative_to(PACKAGE.parent)}:{node.name}", length, EXEMPT_MARK in body))
    return out


def test_the_package_has_functions() -> None:
    """The walk finds the solver and the cascade (the test would pass vacuously otherwise)."""
    names = {name for name, _, _ in _functions()}
    assert "tpik/solver.py:solve" in names and "tpik/cascade.py:search_modes" in names


@pytest.mark.parametrize(("name", "length", "exempt"), _functions(), ids=lambda v: v if isinstance(v, str) else "")
def test_function_is_short(name: str, length: int, exempt: bool) -> None:
    if exempt:
        return
    assert length <= MAX_LINES, (
        f"{name} has {length} lines (> {MAX_LINES}): split it, or mark a kernel '{EXEMPT_MARK}: <why>'"
    )

"""No function of qp_baseline/ is longer than 60 lines of code ("no function on the control path
longer than ~60 lines").

A function's length is its lines from ``def`` to its last line, its docstring left out (the docstrings
carry the math and the argument list the style asks for). Only qp_baseline/ is checked here: tpik/ and
compare/loop/ are being split by their own owners, who add their packages to this test.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

MAX_LINES = 60
ROOT = Path(__file__).resolve().parents[1]
MODULES = sorted((ROOT / "qp_baseline").rglob("*.py"))


def code_lines(node: ast.FunctionDef | ast.AsyncFunctionDef) -> int:
    """Lines of ``node`` without its docstring."""
    assert node.end_lineno is not None
    total = node.end_lineno - node.lineno + 1
    first = node.body[0]
    if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant) and isinstance(first.value.value, str):
        assert first.end_lineno is not None
        total -= first.end_lineno - first.lineno + 1
    return total


def long_functions(source: str) -> list[str]:
    """``name (lines)`` of every function (methods and nested ones too) above :data:`MAX_LINES`."""
    tree = ast.parse(source)
    return [
        f"{node.name} (line {node.lineno}: {code_lines(node)} lines)"
        for node in ast.walk(tree)
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef) and code_lines(node) > MAX_LINES
    ]


def test_the_measure_counts_code_not_docstrings():
    body = "\n".join(f"    x{i} = {i}" for i in range(MAX_LINES))
    doc = '    """Doc.\n\n' + "    more\n" * 30 + '    """\n'
    assert long_functions(f"def f():\n{doc}{body}\n") == ["f (line 1: 61 lines)"]
    assert long_functions(f"def f():\n{doc}{body[: body.rindex(chr(10))]}\n") == []


def test_qp_baseline_has_modules():
    assert len(MODULES) >= 5


@pytest.mark.parametrize("module", MODULES, ids=lambda p: str(p.relative_to(ROOT)))
def test_no_function_is_longer_than_60_lines(module: Path):
    assert long_functions(module.read_text()) == []

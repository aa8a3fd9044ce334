"""No function on the control path is longer than 60 lines (named parts, each one job).

Checked: every function and method of ``compare/loop/`` and ``compare/sensing/``, compiled
kernels included. A function's length is its body's (from the first statement after the
docstring to its last line): the signature of a kernel with a dozen array arguments, one a
line, and the docstring that documents them are not logic to split.
"""

from __future__ import annotations

import ast
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[3]
PACKAGES = ("compare/loop", "compare/sensing")
MAX_LINES = 60


def body_lengths(source: str) -> dict[str, int]:
    """Body length [lines] of every function in ``source``, by qualified name."""
    tree = ast.parse(source)
    out: dict[str, int] = {}

    def visit(node: ast.AST, prefix: str) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.FunctionDef | ast.AsyncFunctionDef):
                body = child.body
                first = body[0]
                is_doc = isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant)
                if is_doc and isinstance(first.value.value, str) and len(body) > 1:
                    first = body[1]
                assert child.end_lineno is not None
                out[prefix + child.name] = child.end_lineno - first.lineno + 1
                visit(child, f"{prefix}{child.name}.")
            elif isinstance(child, ast.ClassDef):
                visit(child, f"{prefix}{child.name}.")

    visit(tree, "")
    return out


def _files() -> list[Path]:
    return sorted(p for pkg in PACKAGES for p in (ROOT / pkg).glob("*.py"))


def test_the_measure_counts_the_body_and_not_the_docstring():
    body = "\n".join(f"    x{i} = {i}" for i in range(61))
    head = 'def long(a,\n         b):\n    """Doc.\n\n    More.\n    """\n'
    source = f"{head}{body}\n\n\nclass A:\n    def short(self):\n        return 1\n"
    assert body_lengths(source) == {"long": 61, "A.short": 1}
    nested = textwrap.dedent(
        """
        def outer():
            def inner():
                return 2
            return inner
        """
    )
    assert body_lengths(nested) == {"outer": 3, "outer.inner": 1}


def test_the_control_path_packages_are_found():
    names = {p.name for p in _files()}
    assert {"closed_loop.py", "sensing_gate.py", "fusion.py", "_kernels.py", "_fusion_kernel.py"} <= names


@pytest.mark.parametrize("path", _files(), ids=lambda p: f"{p.parent.name}/{p.name}")
def test_no_function_is_longer_than_60_lines(path: Path):
    lengths = body_lengths(path.read_text(encoding="utf-8"))
    long = {name: n for name, n in lengths.items() if n > MAX_LINES}
    assert not long, f"{path.relative_to(ROOT)}: functions longer than {MAX_LINES} lines: {long}"

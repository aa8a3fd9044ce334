"""Every file path and module that README.md, the docs and the code's docstrings cite exists."""

from __future__ import annotations

import importlib.util
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PATH = re.compile(r"(?<![\w./-])((?:robots|tpik|qp_baseline|compare|tests|configs|docs|scripts|\.ci)/[\w./-]*\w)")
MODULE = re.compile(r":(?:mod|func|class|data|meth):`~?((?:robots|tpik|qp_baseline|compare)(?:\.\w+)+)`")
WRITTEN_BY_THE_READER = {"tpik/tasks/elbow_height_task.py"}  # docs/extending.md has the reader write it
SOURCES = sorted(
    [ROOT / "README.md", *(ROOT / "docs").rglob("*.md")]
    + [p for d in ("robots", "tpik", "qp_baseline", "compare", "scripts", "tests") for p in (ROOT / d).rglob("*.py")]
)


def _cited(text: str) -> set[str]:
    paths = {m.group(1).rstrip(".") for m in PATH.finditer(text)}
    return {p for p in paths if not any(ch in p for ch in "*<>{}[]") and p not in WRITTEN_BY_THE_READER}


@pytest.mark.parametrize("source", SOURCES, ids=[str(p.relative_to(ROOT)) for p in SOURCES])
def test_cited_paths_exist(source: Path):
    missing = sorted(p for p in _cited(source.read_text(encoding="utf-8")) if not (ROOT / p).exists())
    assert not missing, f"{source.relative_to(ROOT)} cites files that do not exist: {missing}"


def _resolves(dotted: str) -> bool:
    """A module, or an attribute path inside one (``compare.loop.closed_loop.run_loop``)."""
    parts = dotted.split(".")
    for k in range(len(parts), 0, -1):
        name = ".".join(parts[:k])
        try:
            found = importlib.util.find_spec(name) is not None
        except ModuleNotFoundError:  # a name inside a module, not a submodule
            found = False
        if found:
            if k == len(parts):
                return True
            obj = importlib.import_module(name)
            for attr in parts[k:]:
                if not hasattr(obj, attr):
                    return False
                obj = getattr(obj, attr)
            return True
    return False


def test_cited_modules_and_names_exist():
    missing = []
    for source in SOURCES:
        for m in MODULE.finditer(source.read_text(encoding="utf-8")):
            if not _resolves(m.group(1)):
                missing.append(f"{source.relative_to(ROOT)}: {m.group(1)}")
    assert not missing, "cited modules or names that do not exist:\n" + "\n".join(missing)

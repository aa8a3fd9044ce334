"""Every file, module and name that README.md, the docs and the code cite exists.

Scanned: README.md, every ``docs/**/*.md`` and every ``.py`` file of the packages and the tests
(docstrings, comments and strings alike). Checked:

* **paths** under the project's top-level folders (``compare/loop/faults.py``, ``tests/...py``,
  ``configs/case1.toml``, ``docs/design.md``, ``robots/...``), a ``:line`` suffix allowed;
* **relative links** of the Markdown files (``[text](sensing.md)``, images), from the file's folder;
* **dotted modules and names** of the packages, in backquotes (```compare.loop.faults```,
  ``:mod:`compare.x```, ``:func:`~compare.x.f```) or after ``python -m``: the module file must
  exist and each further name must be defined in it (a function, class, constant, a name it
  imports from elsewhere in the project, a class member or an attribute ``self.<name>`` set in it).

Not checked: URLs (``https://…/compare/x.py`` belongs to another repository), what a command
writes (the argument of ``--out``, ``--plot``, ``--csv``, ``--json``, ``--export-qps``, ``-o``
and redirections), glob patterns and placeholders (``configs/*.toml``, ``runs/<index>/``,
``{name}``), ``__pycache__``, and the files a guide has the reader write.

The names are resolved by reading the modules' syntax trees, not by importing them: the whole
check takes well under a second.
"""

from __future__ import annotations

import ast
import functools
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("robots", "tpik", "qp_baseline", "compare")
TOP = (*PACKAGES, "tests", "configs", "docs", "scripts", ".ci")

PATH = re.compile(rf"(?<![\w./:-])((?:{'|'.join(map(re.escape, TOP))})/[\w./-]*\w)")
OUTPUT_OPTION = re.compile(r"(?:--out|--plot|--csv|--json|--export-qps|--savefig|-o|>)[ =]+$")
LINK = re.compile(r"\]\(([^)\s]+)\)")
DOTTED = rf"~?((?:{'|'.join(PACKAGES)})(?:\.\w+)+)"
MODULE = re.compile(rf"(?::(?:mod|func|class|data|meth|attr|obj|exc):)?`{{1,2}}{DOTTED}(?:\(\))?`{{1,2}}")
PYTHON_M = re.compile(rf"python3? -m ((?:{'|'.join(PACKAGES)})(?:\.\w+)*)")
FROM_IMPORT = re.compile(rf"^\s*from ((?:{'|'.join(PACKAGES)})(?:\.\w+)*) import \(?([\w, ]+)", re.M)

WRITTEN_BY_THE_READER = {"tpik/tasks/elbow_height_task.py"}  # docs/extending.md has the reader write it
SOURCES = sorted(
    [ROOT / "README.md", *(ROOT / "docs").rglob("*.md")]
    + [p for d in (*PACKAGES, "scripts", "tests") for p in (ROOT / d).rglob("*.py") if p != Path(__file__).resolve()]
)
FILE_SUFFIXES = {"md", "py", "toml", "json", "xml", "urdf", "csv", "png", "svg", "txt", "parquet", "npz", "rrd", "mp4"}


def _placeholder(path: str) -> bool:
    return any(ch in path for ch in "*<>{}[]") or "__pycache__" in path or path in WRITTEN_BY_THE_READER


def cited_paths(text: str) -> set[str]:
    """Project paths cited in ``text`` that must exist (not outputs, globs or placeholders)."""
    out = set()
    for m in PATH.finditer(text):
        path = m.group(1).rstrip(".")
        line_start = text.rfind("\n", 0, m.start()) + 1
        if OUTPUT_OPTION.search(text[line_start : m.start()]) or _placeholder(path):
            continue
        out.add(path)
    return out


def cited_links(text: str, folder: Path) -> set[Path]:
    """Targets of the relative Markdown links of ``text``, resolved from ``folder``."""
    out = set()
    for m in LINK.finditer(text):
        target = m.group(1).split("#", 1)[0]
        if not target or re.match(r"^[a-z][a-z0-9+.-]*:", target) or _placeholder(target):
            continue
        out.add((folder / target).resolve())
    return out


def cited_names(text: str, markdown: bool = False) -> set[str]:
    """Dotted modules and names of the packages cited in ``text`` (a file name such as ``robots.md`` is not one).

    With ``markdown``, also the imports of its code examples (``from compare.x import f, g``).
    """
    found = {m.group(1) for m in MODULE.finditer(text)} | {m.group(1) for m in PYTHON_M.finditer(text)}
    if markdown:
        for m in FROM_IMPORT.finditer(text):
            found |= {f"{m.group(1)}.{name.strip()}" for name in m.group(2).split(",") if name.strip()}
    return {name for name in found if name.rsplit(".", 1)[-1] not in FILE_SUFFIXES}


def _module_file(parts: tuple[str, ...]) -> Path | None:
    base = ROOT.joinpath(*parts)
    for candidate in (base.with_suffix(".py"), base / "__init__.py"):
        if candidate.is_file():
            return candidate
    return None


@functools.cache
def _tree(path: Path) -> ast.Module:
    return ast.parse(path.read_text(encoding="utf-8"))


def _top_level(body: list[ast.stmt]) -> dict[str, ast.AST]:
    """Names a module (or class) body binds, through ``if``/``try``/``with`` blocks."""
    names: dict[str, ast.AST] = {}
    for node in body:
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
            names[node.name] = node
        elif isinstance(node, ast.Assign | ast.AnnAssign | ast.AugAssign):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            for target in targets:
                for leaf in ast.walk(target):
                    if isinstance(leaf, ast.Name):
                        names[leaf.id] = node
        elif isinstance(node, ast.Import | ast.ImportFrom):
            for alias in node.names:
                names[(alias.asname or alias.name).split(".")[0]] = node
        elif isinstance(node, ast.If | ast.Try | ast.With | ast.For):
            inner = [*node.body, *getattr(node, "orelse", []), *getattr(node, "finalbody", [])]
            for handler in getattr(node, "handlers", []):
                inner += handler.body
            names.update(_top_level(inner))
    return names


def _class_members(cls: ast.ClassDef) -> set[str]:
    members = set(_top_level(cls.body))
    for node in ast.walk(cls):
        if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id == "self":
            if isinstance(node.ctx, ast.Store):
                members.add(node.attr)
    return members


def _resolve_in(module: tuple[str, ...], names: list[str], depth: int = 0) -> bool:
    """Whether ``names`` (attribute path) is defined in the project module ``module``."""
    if not names or depth > 8:
        return True
    path = _module_file(module)
    if path is None:
        return False
    first, rest = names[0], names[1:]
    if _module_file((*module, first)) is not None:  # a submodule
        return _resolve_in((*module, first), rest, depth + 1)
    node = _top_level(_tree(path).body).get(first)
    if node is None:
        return False
    if isinstance(node, ast.ImportFrom) and node.module and node.module.split(".")[0] in PACKAGES:
        alias = next(a for a in node.names if (a.asname or a.name) == first)
        return _resolve_in(tuple(node.module.split(".")), [alias.name, *rest], depth + 1)
    if isinstance(node, ast.ClassDef) and rest:
        if rest[0] in _class_members(node):
            return True
        bases = [b for b in node.bases if not (isinstance(b, ast.Name) and b.id in ("object", "Protocol"))]
        return bool(bases)  # inherited from a base (not followed): accepted
    return True  # a function, a constant or a name from outside the project: its attributes are not checked


def resolves(dotted: str) -> bool:
    """Whether a cited dotted module or name exists in the project."""
    parts = dotted.split(".")
    if _module_file((parts[0],)) is None:
        return False
    return _resolve_in((parts[0],), parts[1:])


def test_cited_paths_and_links_exist():
    missing = []
    for source in SOURCES:
        text = source.read_text(encoding="utf-8")
        rel = source.relative_to(ROOT)
        missing += [f"{rel}: {p}" for p in sorted(cited_paths(text)) if not (ROOT / p).exists()]
        if source.suffix == ".md":
            missing += [f"{rel}: link {t}" for t in sorted(cited_links(text, source.parent)) if not t.exists()]
    assert not missing, "cited files that do not exist:\n" + "\n".join(missing)


def runnable(module: str) -> bool:
    """Whether ``python -m module`` runs something: a module with a main block, or a package's ``__main__``."""
    parts = tuple(module.split("."))
    main = _module_file((*parts, "__main__"))
    if main is not None:
        return True
    path = _module_file(parts)
    return path is not None and path.name != "__init__.py" and "__main__" in path.read_text(encoding="utf-8")


def test_cited_modules_and_names_exist():
    missing = []
    for source in SOURCES:
        text = source.read_text(encoding="utf-8")
        for dotted in sorted(cited_names(text, source.suffix == ".md")):
            if not resolves(dotted):
                missing.append(f"{source.relative_to(ROOT)}: {dotted}")
        for module in sorted({m.group(1) for m in PYTHON_M.finditer(text)}):
            if resolves(module) and not runnable(module):
                missing.append(f"{source.relative_to(ROOT)}: python -m {module} (nothing to run)")
    assert not missing, "cited modules or names that do not exist:\n" + "\n".join(missing)


def test_the_checks_catch_what_they_are_for():
    text = (
        "see compare/loop/faults.py:29 and tests/compare/test_nowhere.py; "
        "`compare.loop.faults.FaultInjector.summarize`, :func:`~compare.nowhere.f`, "
        "python -m compare.bench.sensing; https://github.com/x/y/blob/main/compare/z.py; "
        "tpik-compare run configs/case1.toml --out docs/new-campaign; configs/*.toml; runs/<index>/"
    )
    assert cited_paths(text) == {"compare/loop/faults.py", "tests/compare/test_nowhere.py", "configs/case1.toml"}
    names = cited_names(text)
    assert names == {"compare.loop.faults.FaultInjector.summarize", "compare.nowhere.f", "compare.bench.sensing"}
    assert resolves("compare.loop.faults.FaultInjector.summarize") and resolves("compare.bench.sensing")
    assert resolves("tpik.TpikSolver") and resolves("qp_baseline.hqp.HqpSolver.qp_log")
    assert not resolves("compare.nowhere.f") and not resolves("compare.loop.faults.NoSuchThing")
    assert runnable("compare.bench.sensing") and not runnable("compare.bench") and not runnable("compare.loop.faults")
    assert cited_names("    from compare.bench.suite import correctness_table, run_bench", markdown=True) == {
        "compare.bench.suite.correctness_table",
        "compare.bench.suite.run_bench",
    }
    assert cited_links("[a](sensing.md) [b](https://x.org/a.md) [c](#top)", ROOT / "docs") == {
        ROOT / "docs" / "sensing.md"
    }

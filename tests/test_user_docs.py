"""The user documentation reads as documentation: no issue numbers, commit hashes or first person.

Checked on README.md and the hand-written pages ``docs/*.md``; the reports inside result folders
(``docs/<folder>/*.md``) are written by the tools and keep their provenance (the git commit).
``docs/benchmarks.md`` stays a page (at most :data:`BENCHMARKS_MAX_LINES` lines); its history is
CHANGELOG.md's.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
BENCHMARKS_MAX_LINES = 500

_ISSUE = re.compile(r"\b[Ii]ssues? #?\d+")
_FIRST_PERSON = re.compile(r"\b(?:[Ww]e|[Oo]ur|[Oo]urs|[Oo]urselves|[Mm]y|me)\b|(?<![=/] )(?<![/])\bI\b(?![/.])")
_HEX = re.compile(r"(?<![\w./#-])([0-9a-f]{7,40})(?![\w.-])")


def _is_hash(token: str) -> bool:
    """A git hash (7–40 hex digits, letters and digits both), not a number or an MD5 sum (32 digits)."""
    if len(token) == 32 or not (re.search(r"[a-f]", token) and re.search(r"\d", token)):
        return False
    try:
        float(token)
    except ValueError:
        return True
    return False


def findings(text: str) -> list[str]:
    """What a user page must not hold, one line each (``line: what``); MD5 sums are allowed."""
    out = []
    for number, line in enumerate(text.splitlines(), start=1):
        if "MD5" in line or "md5" in line:
            continue
        out += [f"{number}: issue number '{m.group(0)}'" for m in _ISSUE.finditer(line)]
        out += [f"{number}: first person '{m.group(0)}'" for m in _FIRST_PERSON.finditer(line)]
        out += [f"{number}: commit hash '{m.group(1)}'" for m in _HEX.finditer(line) if _is_hash(m.group(1))]
    return out


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.relative_to(ROOT).as_posix())
def test_a_user_page_has_no_issue_number_hash_or_first_person(page: Path) -> None:
    assert findings(page.read_text(encoding="utf-8")) == []


def test_benchmarks_page_is_a_page() -> None:
    lines = (ROOT / "docs" / "benchmarks.md").read_text(encoding="utf-8").count("\n")
    assert lines <= BENCHMARKS_MAX_LINES


def test_the_checker_finds_what_it_must_and_nothing_else() -> None:
    clean = "Robot I/O at K = I s⁻¹; 1e6 steps; colour #a1b2c3; MD5 `bf16c4e5154848a0`; the `us` unit."
    assert findings(clean) == []
    planted = "As of issue 21 we measured code `1caf301`; I think our figures hold."
    kinds = [f.split(": ", 1)[1].split(" '")[0] for f in findings(planted)]
    assert kinds.count("issue number") == 1 and kinds.count("commit hash") == 1
    assert kinds.count("first person") == 3  # we, I, our

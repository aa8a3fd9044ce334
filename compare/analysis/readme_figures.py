"""README.md's and the docs' result tables, generated from the results files committed in ``docs/``.

A generated table sits between two marker lines of a Markdown file (README.md or ``docs/**/*.md``)::

    <!-- figures:fair-campaign -->
    | method | joint-limit/wall violation | ... |

    <!-- /figures -->

:data:`FIGURES` names each table, the results file it is read from and the function that renders
it. ``python -m compare.analysis.readme_figures`` (``make docs-figures``) rewrites every marked table;
``--check`` writes nothing and exits 1 when a table differs from what its file gives
(``tests/test_readme_figures.py``). A marker naming no figure, a block without its end, a figure in
no document or an unreadable results file is one line and exit code 2.
"""

from __future__ import annotations

import json
import re
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from compare.analysis.atomic_files import write_text_atomic
from compare.analysis.claims_tables import claims_markdown
from compare.analysis.report import markdown_table
from compare.arguments import ArgumentParser, existing_dir
from compare.exceptions import CompareError

ROOT = Path(__file__).resolve().parents[2]
"""The project checkout whose README.md and docs/ are rewritten by default."""

BEGIN = re.compile(r"^<!-- figures:([\w-]+) -->$", re.M)
END = "<!-- /figures -->"


class FiguresError(CompareError):
    """A marker, a document or a results file the tables cannot be generated from (one line)."""


# ------------------------------------------------------------------------------------ formatting


def _percent(x: float) -> str:
    """``0.4`` for 0.0038, ``0`` for 0 (one decimal, a trailing ``.0`` dropped)."""
    text = f"{100.0 * x:.1f}"
    return text[:-2] if text.endswith(".0") else text


def _held(rate: dict[str, Any]) -> str:
    """``47.2 % [42.9, 51.6]``: a rate with its Wilson 95 % interval."""
    lo, hi = rate["ci95"]
    return f"{100.0 * rate['rate']:.1f} % [{100.0 * lo:.1f}, {100.0 * hi:.1f}]"


_SUPERSCRIPT = str.maketrans("-0123456789", "⁻⁰¹²³⁴⁵⁶⁷⁸⁹")


def p_value(p: float) -> str:
    """A p-value as the docs print it: ``0.058``, ``2·10⁻⁶⁰``, ``10⁻⁶³`` (one digit below 10⁻³)."""
    if p >= 1e-3:
        return format(p, ".2g")
    mantissa, exponent = f"{p:.0e}".split("e")
    power = "10" + str(int(exponent)).translate(_SUPERSCRIPT)
    return power if mantissa == "1" else f"{mantissa}·{power}"


def _bold(text: str, best: bool) -> str:
    return f"**{text}**" if best else text


# ---------------------------------------------------------------------------------------- tables


def fair_campaign_table(summary: dict[str, Any]) -> str:
    """README's fair-campaign table from a ``sweep_summary.json`` (docs/design.md §7).

    Per method: runs with a joint-limit or wall safety violation (the fewest in bold, with the
    Wilson 95 % interval), the share with an obstacle violation, failed steps (with their share),
    the time below a physical threshold summed over the runs, the median of the runs' median
    solve times.
    """
    methods: dict[str, dict[str, Any]] = summary.get("methods") or {}
    if not methods:
        raise FiguresError("the sweep summary has no method")
    labels = (summary.get("oracle") or {}).get("labels") or {}
    avoidable = labels.get("avoidable") or {}
    every = bool(avoidable) and avoidable.get("count") == avoidable.get("runs") == summary.get("runs")
    headers = [
        "method",
        "joint-limit/wall violation",
        "obstacle violation" + (" (every run avoidable)" if every else ""),
        "failed steps",
        "time below a physical threshold",
        "solve median",
    ]
    fewest = min(m["share_runs_limit_or_wall_violation"]["count"] for m in methods.values())
    rows = []
    for name, m in methods.items():
        lw = m["share_runs_limit_or_wall_violation"]
        violation = f"{lw['count']}/{lw['runs']}"
        if lw["count"] == fewest:
            lo, hi = lw["ci95"]
            violation = f"**{violation}** [{_percent(lo)}, {_percent(hi)} %]"
        failed = m["status_steps"]["failed"]
        rows.append(
            [
                f"`{name}`",
                violation,
                f"{100.0 * m['share_runs_obstacle_violation']['rate']:.1f} %",
                f"{failed} ({100.0 * m['share_steps_failed']:.1f} %)" if failed else "0",
                f"{m['time_below_physical_s']:.1f} s",
                f"{m['solve_time_us']['median_of_medians']:.0f} µs",
            ]
        )
    return markdown_table(headers, rows)


def prediction_table(setups: dict[str, Any]) -> str:
    """A two-setup table of docs/separating.md (prediction off against estimated, depth against geometric).

    From a ``setups.json`` of two setups, per method, the baseline setup against the other
    (:mod:`compare.campaign.setups`): runs that held the obstacle threshold in each (the most with
    the other setup in bold), the seeds held in one only (exact McNemar p), joint / wall violations
    with the other setup, the mean EE error and the waypoints reached in both.
    """
    baseline = setups.get("baseline")
    others = [name for name in setups.get("setups") or {} if name != baseline]
    if len(others) != 1:
        raise FiguresError(f"a prediction table compares two setups; this file has {len(others) + 1}")
    other = others[0]
    methods: dict[str, dict[str, Any]] = setups.get("methods") or {}
    headers = [
        "method",
        f"held, {baseline}",
        f"held, {other}",
        f"held only {other} / only {baseline} (McNemar p)",
        f"joint / wall violations, {other}",
        f"mean EE error [m], {baseline} → {other}",
        f"waypoints reached, {baseline} → {other}",
    ]
    most = max(m["setups"][other]["held"]["rate"] for m in methods.values())
    rows = []
    for name, m in methods.items():
        a, b = m["setups"][baseline], m["setups"][other]
        vs = b["vs_baseline"]
        rows.append(
            [
                f"`{name}`",
                _held(a["held"]),
                _bold(_held(b["held"]), b["held"]["rate"] == most),
                f"{vs['only_this']} / {vs['only_baseline']} ({p_value(vs['mcnemar_p'])})",
                f"{b['joint_violations']} / {b['wall_violations']}",
                f"{a['ee_error_mean_m']:.3f} → {b['ee_error_mean_m']:.3f}",
                f"{a['waypoints_mean']:.2f} → {b['waypoints_mean']:.2f}",
            ]
        )
    return markdown_table(headers, rows, right=False)


@dataclass(frozen=True)
class Figure:
    """One generated table.

    Attributes:
        name: Its marker name (``<!-- figures:<name> -->``).
        source: The results file it is read from, relative to the checkout.
        render: The table (Markdown) from the file's JSON.
    """

    name: str
    source: str
    render: Callable[[dict[str, Any]], str]


FIGURES: tuple[Figure, ...] = (
    Figure("fair-campaign", "docs/campaign-fair/sweep_summary.json", fair_campaign_table),
    Figure("predicted-campaign", "docs/campaign-predicted/setups.json", prediction_table),
    Figure("depth-campaign", "docs/campaign-predicted/depth/setups.json", prediction_table),
    Figure("depth-vs-geometric", "docs/campaign-predicted/depth-vs-geometric/setups.json", prediction_table),
    Figure("paper-claims", "docs/separating/claims.json", claims_markdown),
    Figure("paper-claims-predicted", "docs/separating/claims-predicted.json", claims_markdown),
)


# ------------------------------------------------------------------------------------- documents


def documents(root: Path) -> list[Path]:
    """The Markdown files scanned for markers: README.md and ``docs/**/*.md``."""
    return [Path(root) / "README.md", *sorted((Path(root) / "docs").rglob("*.md"))]


def tables(root: Path) -> dict[str, str]:
    """Every figure's table, from its results file under ``root``.

    Raises:
        FiguresError: A results file is missing, not JSON, or lacks what its table needs.
    """
    out = {}
    for figure in FIGURES:
        path = Path(root) / figure.source
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
            out[figure.name] = figure.render(data)
        except OSError as exc:
            raise FiguresError(f"{path}: cannot read ({exc.strerror})") from None
        except json.JSONDecodeError as exc:
            raise FiguresError(f"{path}: not JSON ({exc.msg}, line {exc.lineno})") from None
        except (KeyError, TypeError, ValueError) as exc:
            what = f"no key {exc}" if isinstance(exc, KeyError) else f"{type(exc).__name__}: {exc}"
            raise FiguresError(f"{path}: cannot make the {figure.name} table ({what})") from None
    return out


def fill(text: str, generated: dict[str, str], where: str = "document") -> tuple[str, list[str]]:
    """``text`` with every marked block replaced by its table; also the names of the blocks found.

    Raises:
        FiguresError: A marker names no figure, or a block has no end marker.
    """
    out, found, pos = [], [], 0
    for match in BEGIN.finditer(text):
        if match.start() < pos:
            continue
        name = match.group(1)
        if name not in generated:
            raise FiguresError(f"{where}: <!-- figures:{name} --> names no figure; one of {', '.join(generated)}")
        end = text.find("\n" + END, match.end())
        if end < 0:
            raise FiguresError(f"{where}: <!-- figures:{name} --> has no {END} after it")
        out += [text[pos : match.end()], "\n", generated[name], "\n\n"]  # a blank line ends the table
        found.append(name)
        pos = end + 1
    out.append(text[pos:])
    return "".join(out), found


def generate(root: Path = ROOT) -> dict[Path, tuple[str, str]]:
    """Each document holding a marker: ``{path: (current text, generated text)}``.

    Raises:
        FiguresError: See :func:`tables` and :func:`fill`; also a figure in no document.
    """
    root = Path(root)
    if not (root / "README.md").is_file():
        raise FiguresError(f"{root}: no README.md (not a checkout of the project)")
    generated = tables(root)
    out: dict[Path, tuple[str, str]] = {}
    seen: set[str] = set()
    for path in documents(root):
        if not path.is_file():
            continue
        text = path.read_text(encoding="utf-8")
        new, found = fill(text, generated, str(path.relative_to(root)))
        if found:
            out[path] = (text, new)
            seen.update(found)
    missing = [figure.name for figure in FIGURES if figure.name not in seen]
    if missing:
        raise FiguresError(f"no document holds <!-- figures:{missing[0]} --> (README.md, docs/**/*.md)")
    return out


def stale(root: Path = ROOT) -> list[Path]:
    """The documents whose generated tables differ from their results files."""
    return [path for path, (text, new) in generate(root).items() if text != new]


def main(argv: list[str] | None = None) -> int:
    """Rewrite the generated tables (``--check``: only compare, exit 1 when one is out of date)."""
    parser = ArgumentParser(
        prog="python -m compare.analysis.readme_figures",
        description="Rewrite the result tables of README.md and docs/ between <!-- figures:NAME --> markers"
        " from the results files committed in docs/.",
    )
    parser.add_argument("--check", action="store_true", help="write nothing; exit 1 when a table is out of date")
    parser.add_argument("--root", type=existing_dir, default=ROOT, help="the project checkout (default: this one)")
    args = parser.parse_args(argv)
    try:
        generated = generate(args.root)
    except FiguresError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    changed = [path for path, (text, new) in generated.items() if text != new]
    if args.check:
        for path in changed:
            print(f"{path} is out of date: make docs-figures", file=sys.stderr)
        return 1 if changed else 0
    for path in changed:
        write_text_atomic(path, generated[path][1])
        print(path)
    return 0


if __name__ == "__main__":
    sys.exit(main())

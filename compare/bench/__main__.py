"""``python -m compare.bench``: solver and sensing micro-benchmarks (DESIGN §7 ``bench``).

Examples::

    python -m compare.bench                                   # solvers and sensing
    python -m compare.bench --only solvers --methods tpik mink --repeats 500 --json bench.json
    python -m compare.bench --only sensing
    python -m compare.bench --only solvers --config configs/panda_case2.toml   # that config's robot and levels

Prints tables (medians, p95, ratio to ``mink-native`` — the same problem written with mink alone
— measured in the same interleaved run; ``mink`` is the project's adapter, timed beside it) and,
with ``--json``, writes ``{"versions": ..., "command": ..., "results": [row, ...]}`` (DESIGN §7;
``ratio_to_mink`` of a row is against ``mink-native``).
"""

from __future__ import annotations

import argparse
import importlib
import json
import shlex
import sys
from pathlib import Path

from rich.console import Console
from rich.table import Table

from compare.bench.solvers import DEFAULT_METHODS, run_candidate_bench, run_solver_bench
from compare.bench.timing import BenchRow
from compare.versions import versions
from robots import DEFAULT_ROBOT


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m compare.bench", description=__doc__.splitlines()[0])
    p.add_argument(
        "--methods",
        nargs="+",
        default=DEFAULT_METHODS,
        help=f"methods for the case-2 table (default: {' '.join(DEFAULT_METHODS)})",
    )
    p.add_argument("--repeats", type=int, default=300, help="timed calls per method and case (default 300)")
    p.add_argument("--json", type=Path, default=None, help="write the results as JSON to this file")
    p.add_argument("--only", choices=("solvers", "sensing"), default=None, help="run one group only")
    p.add_argument(
        "--config",
        type=Path,
        default=None,
        help="scenario TOML whose robot, levels (the case-2 hierarchy) and method settings are used "
        "(default: the paper's case 2 on the default robot)",
    )
    p.add_argument(
        "--max-candidates",
        type=int,
        default=8,
        help="largest |C| of the TPIK-vs-candidates table, 0..12; -1 skips it (default 8)",
    )
    return p


LABELS = {"mink": "mink (project adapter)", "mink-native": "mink-native (reference)"}
"""Table labels; the JSON keeps the method names."""


def _fmt(value: float | None, digits: int = 1) -> str:
    return "" if value is None else f"{value:.{digits}f}"


def solver_table(rows: list[BenchRow], title: str) -> Table:
    """Rich table of solver rows: median, p95, ratio to mink-native, build/solve split."""
    table = Table(title=title)
    for col, justify in (
        ("method", "left"),
        ("case", "left"),
        ("median [µs]", "right"),
        ("p95 [µs]", "right"),
        ("× mink (native)", "right"),
        ("build [µs]", "right"),
        ("solve [µs]", "right"),
        ("active", "right"),
        ("modes", "right"),
    ):
        table.add_column(col, justify=justify)  # type: ignore[arg-type]
    for r in rows:
        e = r.extra
        table.add_row(
            LABELS.get(r.name, r.name),
            r.case,
            _fmt(r.median_us),
            _fmt(r.p95_us),
            _fmt(e.get("ratio_to_mink"), 2),
            _fmt(e.get("build_us")),
            _fmt(e.get("solve_us")),
            _fmt(e.get("active"), 0),
            _fmt(e.get("modes_evaluated"), 0),
        )
    return table


def _generic_table(rows: list[BenchRow], title: str) -> Table:
    table = Table(title=title)
    for col in ("stage", "case", "median [µs]", "p95 [µs]", "notes"):
        table.add_column(col)
    for r in rows:
        notes = ", ".join(f"{k}={v:.4g}" for k, v in r.extra.items())
        table.add_row(r.name, r.case, _fmt(r.median_us), _fmt(r.p95_us), notes)
    return table


def main(argv: list[str] | None = None) -> int:
    """Run the benchmarks; returns the process exit code."""
    args_list = sys.argv[1:] if argv is None else list(argv)
    args = _parser().parse_args(args_list)
    if args.repeats < 1:
        print("--repeats must be >= 1", file=sys.stderr)
        return 2
    if not -1 <= args.max_candidates <= 12:
        print("--max-candidates must be in -1..12", file=sys.stderr)
        return 2
    robot, description, settings = None, None, None
    if args.config is not None:
        from compare.config import ConfigError, load_config

        try:
            config, _ = load_config(args.config)
        except ConfigError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
        robot, description, settings = config.load_robot(), config.hierarchy_description(), config.methods.settings
    console = Console(width=max(Console().width, 132))
    info = versions()
    console.print(
        f"python {info.get('python')} · numpy {info.get('numpy')} · pin {info.get('pin')} · "
        f"mujoco {info.get('mujoco')} · mink {info.get('mink')} · cpu {info.get('cpu')} ({info.get('machine')})"
    )
    rows: list[BenchRow] = []
    if args.only in (None, "solvers"):
        case2 = run_solver_bench(list(args.methods), args.repeats, robot, description, settings)
        where = f"{args.config} ({robot.name})" if robot is not None else "case-2 hierarchy"
        console.print(solver_table(case2, f"Solvers, {where}: one step incl. kinematics"))
        rows += case2
        if args.max_candidates >= 0:
            cands = run_candidate_bench(args.repeats, args.max_candidates, robot=robot)
            console.print(solver_table(cands, "TPIK vs number of candidate set tasks |C|"))
            rows += cands
    if args.only in (None, "sensing"):
        try:
            sensing = importlib.import_module("compare.bench.sensing")
        except ImportError as exc:
            console.print(f"note: sensing benchmark unavailable: {exc}")
        else:
            sens = sensing.run_sensing_bench(args.repeats, robot)
            console.print(_generic_table(sens, "Sensing, one 512×424 frame"))
            rows += sens
    if args.json is not None:
        payload = {
            "versions": info,
            "command": "python -m compare.bench " + shlex.join(args_list),
            "robot": robot.name if robot is not None else DEFAULT_ROBOT,
            "results": [r.to_dict() for r in rows],
        }
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(payload, indent=2) + "\n", encoding="utf-8")
        console.print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""``python -m compare.bench``: solver and sensing micro-benchmarks (DESIGN §7 ``bench``).

Examples::

    python -m compare.bench                                   # solvers and sensing
    python -m compare.bench --only solvers --methods tpik mink --repeats 500 --json bench.json
    python -m compare.bench --only sensing
    python -m compare.bench --only solvers --config configs/panda_case2.toml   # that config's robot and levels
    python -m compare.bench --only correctness --rounds 3 --plot time_vs_correctness.png
    python -m compare.bench --only correctness --export-qps qp_testset/
    python -m compare.bench --only plant --sweep results/ref40    # plant alone; a sweep's throughput ceiling
    python -m compare.bench --only loop                           # where a campaign step goes, part by part

Prints tables (medians, p95, ratio to ``mink-native`` — the same problem written with mink alone
— measured in the same interleaved run; ``mink`` is the project's adapter, timed beside it) and,
with ``--json``, writes ``{"versions": ..., "command": ..., "results": [row, ...], "correctness": {...}}``
(DESIGN §7; ``ratio_to_mink`` of a row is against ``mink-native``; ``correctness``: every HQP backend
against the stored lexicographic reference, :mod:`compare.bench.correctness`; ``throughput_ceiling``
with ``--sweep``: :mod:`compare.bench.plant`; ``loop_parts``: :mod:`compare.bench.loop_parts`).
"""

from __future__ import annotations

import argparse
import importlib
import json
import math
import shlex
import sys
from pathlib import Path
from typing import Any

from rich.console import Console
from rich.table import Table

from compare.analysis.metrics import to_jsonable
from compare.analysis.results import CONFIG_FILE
from compare.bench.correctness import HQP_BACKENDS, TOLERANCE, StepRecord, Summary
from compare.bench.solvers import DEFAULT_METHODS, run_candidate_bench, run_solver_bench
from compare.bench.timing import BenchRow
from compare.versions import versions
from robots import DEFAULT_ROBOT

RANDOM_CONFIG = Path(__file__).resolve().parents[2] / "configs" / "random.toml"
"""The randomized family whose plant the ``plant`` group times by default."""


GROUPS = ("solvers", "sensing", "plant", "loop", "correctness")
"""The benchmark groups, in the order a full run makes them (``--only`` picks one)."""

LOOP_METHODS = ("tpik", "hqp-daqp", "mink")
"""The reference campaign's methods: the ``loop`` group's default."""
LOOP_SEEDS = (100001, 100002, 100003)
"""Seeds of the ``loop`` group's timed runs by default (of the reference campaign's 100000–100999)."""


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
    p.add_argument(
        "--only",
        choices=GROUPS,
        default=None,
        help="run one group only",
    )
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
    pl = p.add_argument_group("plant and loop (a sweep's plant alone, its throughput ceiling; a step's parts)")
    pl.add_argument(
        "--family",
        "--plant-config",
        dest="family",
        type=Path,
        default=None,
        help="scenario family whose plant (geometric sensing) and runs are timed "
        "(default: the --sweep's own config.toml, else configs/random.toml)",
    )
    pl.add_argument(
        "--sweep",
        type=Path,
        default=None,
        help="a finished sweep: with its mean solve time per step, the throughput ceiling",
    )
    lp = p.add_argument_group("loop (where a campaign step goes: the closed loop's parts, one method at a time)")
    lp.add_argument(
        "--loop-methods",
        nargs="+",
        default=list(LOOP_METHODS),
        help=f"methods, each alone in its runs (default: {' '.join(LOOP_METHODS)})",
    )
    lp.add_argument(
        "--loop-seeds",
        nargs="+",
        type=int,
        default=list(LOOP_SEEDS),
        help=f"scenario seeds of the timed runs (default: {' '.join(map(str, LOOP_SEEDS))})",
    )
    c = p.add_argument_group("correctness (timing vs correctness of the HQP backends)")
    c.add_argument(
        "--backends",
        nargs="+",
        default=list(HQP_BACKENDS),
        help=f"HQP methods judged against the reference (default: {' '.join(HQP_BACKENDS)})",
    )
    c.add_argument("--rounds", type=int, default=3, help="timed passes over the reference states (default 3)")
    c.add_argument(
        "--tolerance",
        type=float,
        default=TOLERANCE,
        help=f"level error within which a level matches the reference (default {TOLERANCE:g})",
    )
    c.add_argument("--plot", type=Path, default=None, help="write the time-vs-correctness figure (PNG/SVG)")
    c.add_argument("--csv", type=Path, default=None, help="write one row per (state, backend), qpbenchmark-style")
    c.add_argument(
        "--export-qps",
        type=Path,
        default=None,
        help="write the level QPs of the reference states as a qpbenchmark test set in this directory",
    )
    c.add_argument(
        "--export-method", default="hqp-piqp", help="HQP method whose cascade poses the exported QPs (default hqp-piqp)"
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


def correctness_table(summaries: list[Summary], title: str) -> Table:
    """Rich table of :class:`~compare.bench.correctness.Summary` rows."""
    table = Table(title=title)
    for col in (
        "backend",
        "states",
        "correct",
        "rate % [95 % CI]",
        "flagged",
        "silent",
        "worst e_k",
        "primal p95",
        "dual p95",
        "gap p95",
        "median [µs]",
        "p95 [µs]",
        "QPs/step",
    ):
        table.add_column(col, justify="left" if col in ("backend", "states") else "right")

    def sci(value: float | None) -> str:
        return "" if value is None or not math.isfinite(value) else f"{value:.1e}"

    for s in summaries:
        lo, hi = s.success_rate["ci95"]
        table.add_row(
            s.name,
            f"{s.states} ({s.count})",
            str(s.correct),
            f"{100 * s.success_rate['rate']:.1f} [{100 * lo:.1f}, {100 * hi:.1f}]",
            str(s.flagged),
            str(s.silent),
            sci(s.worst_level_error),
            sci(s.primal_residual.get("p95")),
            sci(s.dual_residual.get("p95")),
            sci(s.duality_gap.get("p95")),
            _fmt(s.time_us.get("median")),
            _fmt(s.time_us.get("p95")),
            f"{s.qp_calls_per_step:.2f}",
        )
    return table


def _write_records_csv(records: list[StepRecord], path: Path) -> None:
    """qpbenchmark-style results table: problem, solver, settings, runtime, found, residuals, plus our verdict."""
    import pandas as pd

    rows = [
        {
            "problem": r.state,
            "solver": r.method,
            "settings": "default",
            "runtime": r.time_us * 1e-6,
            "found": r.status != "failed",
            "primal_residual": r.primal_residual,
            "dual_residual": r.dual_residual,
            "duality_gap": r.duality_gap,
            "state_set": r.state_set,
            "status": r.status,
            "verdict": r.verdict,
            "level": r.level,
            "worst_level_error": r.worst_error,
            "flagged": r.flagged,
            "levels_dropped": r.levels_dropped,
            "levels_uncertified": r.levels_uncertified,
            "qp_calls": r.qp_calls,
            "retries": r.retries,
        }
        for r in records
    ]
    path.parent.mkdir(parents=True, exist_ok=True)
    pd.DataFrame(rows).to_csv(path, index=False)


def _run_correctness(args: argparse.Namespace, args_list: list[str], console: Console) -> dict[str, Any] | None:
    from compare.bench.correctness import run_correctness_bench, summarize
    from compare.bench.qp_reference import REFERENCE_FILE, ReferenceMismatch, load_reference

    try:
        entries = load_reference()
    except (FileNotFoundError, ReferenceMismatch) as exc:
        console.print(f"error: correctness bench: {exc}")
        return None
    records = run_correctness_bench(list(args.backends), entries, rounds=args.rounds, tol=args.tolerance)
    summaries = summarize(records)
    console.print(
        correctness_table(
            summaries,
            f"Timing vs correctness: HQP backends vs the lexicographic reference (tolerance {args.tolerance:g}, "
            f"{args.rounds} interleaved rounds)",
        )
    )
    if args.plot is not None:
        from compare.bench.correctness_plot import plot_time_vs_correctness

        console.print(f"wrote {plot_time_vs_correctness(summaries, records, args.plot, args.tolerance)}")
    if args.csv is not None:
        _write_records_csv(records, args.csv)
        console.print(f"wrote {args.csv}")
    if args.export_qps is not None:
        from compare.bench.qp_export import collect_bench_qps, export_test_set

        problems = collect_bench_qps(args.export_method, entries)
        export_test_set(problems, args.export_qps, "python -m compare.bench " + shlex.join(args_list))
        console.print(f"wrote {len(problems)} level QPs of {args.export_method} to {args.export_qps}")
    data = json.loads(REFERENCE_FILE.read_text(encoding="utf-8"))
    return {
        "tolerance": args.tolerance,
        "rounds": args.rounds,
        "reference": {"file": REFERENCE_FILE.name, "fingerprint": data["fingerprint"], "made_with": data["made_with"]},
        "summaries": [to_jsonable(s.to_dict()) for s in summaries],
    }


def plant_config_of(explicit: Path | None, sweep_dir: Path | None) -> Path:
    """The config whose plant is timed: the one given, else the sweep's own copy, else the random family."""
    if explicit is not None:
        return explicit
    if sweep_dir is not None and (sweep_dir / CONFIG_FILE).is_file():
        return sweep_dir / CONFIG_FILE
    return RANDOM_CONFIG


def _run_plant(args: argparse.Namespace, console: Console) -> tuple[BenchRow, dict[str, Any] | None] | None:
    """The plant row and, with ``--sweep``, the throughput ceiling; None after a printed error."""
    from compare.bench.plant import read_sweep_solves, run_plant_bench, throughput_ceiling
    from compare.config import ConfigError, load_config

    try:  # the sweep first: a wrong directory is refused before the plant is timed
        sweep = read_sweep_solves(args.sweep) if args.sweep is not None else None
        plant_config = plant_config_of(args.family, args.sweep)
        config, _ = load_config(plant_config, {"scenario.sensing": "geometric"})
    except (FileNotFoundError, ConfigError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return None
    row = run_plant_bench(config, steps=max(args.repeats, 200))
    console.print(_generic_table([row], f"Plant alone, one control period ({plant_config})"))
    if sweep is None:
        return row, None
    ceiling = {**throughput_ceiling(sweep, row.extra["mean_us"]), "plant_config": str(plant_config)}
    solves = ", ".join(f"{m} {us:.1f}" for m, us in sweep.mean_solve_us.items())
    console.print(
        f"throughput ceiling of {args.sweep}: mean solve per step [µs] {solves} "
        f"(all {ceiling['mean_solve_all_us']:.1f}) + plant {row.extra['mean_us']:.1f} → "
        f"{ceiling['ceiling_sim_s_per_cpu_s']:.1f} simulated s per CPU s"
    )
    return row, ceiling


def _run_loop_parts(args: argparse.Namespace, console: Console) -> tuple[list[BenchRow], dict[str, Any]] | None:
    """The ``loop-step`` rows and the ``loop_parts`` entry; None after a printed error."""
    from compare.bench.loop_parts import OWN_SOLVE, LoopRunFailed, loop_parts_rows, run_loop_parts, wrapper_cost_ns
    from compare.campaign.sweep import seeded_config
    from compare.config import ConfigError, load_config

    family = plant_config_of(args.family, args.sweep)
    try:
        config, _ = load_config(family)
        # The methods (names and settings) checked as a config's are, before any run.
        seeded_config(config, args.loop_seeds[0], list(args.loop_methods))
    except (FileNotFoundError, ConfigError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return None
    cost_ns = wrapper_cost_ns()
    results = []
    for method in args.loop_methods:
        console.print(f"loop parts: {method}, seeds {' '.join(map(str, args.loop_seeds))} ({family}) …")
        try:
            results.append(run_loop_parts(config, method, args.loop_seeds))
        except LoopRunFailed as exc:
            print(f"error: loop parts of {method}: {exc}", file=sys.stderr)
            return None
    rows, entry = loop_parts_rows(results, cost_ns)
    entry["config"] = str(family)
    entry["seeds"] = list(args.loop_seeds)
    table = Table(title=f"Where a control step goes [µs per step, exclusive] ({family.name}, one method per run)")
    table.add_column("part")
    for r in results:
        table.add_column(r.method, justify="right")
    for label in results[0].parts_us:
        table.add_row(label if label != OWN_SOLVE else f"  {label}", *(f"{r.parts_us[label]:.1f}" for r in results))
    table.add_row("[bold]total, profiled", *(f"[bold]{r.total_us:.1f}" for r in results))
    per_method = entry["methods"]
    table.add_row(
        f"  of which timers ({cost_ns:.0f} ns per call)",
        *(f"{per_method[r.method]['timer_cost_us_per_step']:.1f}" for r in results),
    )
    table.add_row("[bold]CPU per step, no timer", *(f"[bold]{r.unprofiled_cpu_us_per_step:.1f}" for r in results))
    console.print(table)
    return rows, entry


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
    if args.rounds < 1:
        print("--rounds must be >= 1", file=sys.stderr)
        return 2
    if not (math.isfinite(args.tolerance) and args.tolerance > 0):
        print("--tolerance must be a finite number > 0", file=sys.stderr)
        return 2
    bad = [b for b in args.backends if not b.startswith("hqp-")]
    if bad:
        print(f"--backends takes hqp-<backend> methods only, got {', '.join(bad)}", file=sys.stderr)
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
    console = Console(width=max(Console().width, 160))
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
    ceiling = None
    if args.only in (None, "plant"):
        plant = _run_plant(args, console)
        if plant is None:
            return 2
        rows.append(plant[0])
        ceiling = plant[1]
    loop_parts = None
    if args.only in (None, "loop"):
        loop = _run_loop_parts(args, console)
        if loop is None:
            return 2
        rows += loop[0]
        loop_parts = loop[1]
    correctness = None
    if args.only in (None, "correctness"):
        correctness = _run_correctness(args, args_list, console)
        if correctness is None:
            return 2
    if args.json is not None:
        payload: dict[str, Any] = {
            "versions": info,
            "command": "python -m compare.bench " + shlex.join(args_list),
            "robot": robot.name if robot is not None else DEFAULT_ROBOT,
            "results": [r.to_dict() for r in rows],
        }
        if correctness is not None:
            payload["correctness"] = correctness
        if ceiling is not None:
            payload["throughput_ceiling"] = ceiling
        if loop_parts is not None:
            payload["loop_parts"] = loop_parts
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(payload, indent=2) + "\n", encoding="utf-8")
        console.print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

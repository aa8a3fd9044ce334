"""``tpik-compare bench``: the solver, sensing and QP-correctness benchmarks (docs/design.md §7).

Examples::

    tpik-compare bench                                          # every group
    tpik-compare bench --only solvers -m tpik -m mink --repeats 500 --json bench.json
    tpik-compare bench --only sensing
    tpik-compare bench --only solvers --config configs/panda_case2.toml   # that config's robot and levels
    tpik-compare bench --only correctness --rounds 3 --plot time_vs_correctness.png
    tpik-compare bench --only correctness --export-qps qp_testset/

:func:`run_bench` prints tables (medians, p95, ratio to ``mink-native`` — the same problem
written with mink alone — measured in the same interleaved run, and the split of the same calls
into the QP solver or compiled step against the rest, with :data:`RATIO_CAPTION` under each;
``mink`` is the project's adapter, timed beside it) and, with ``json_out``, writes ``{"versions": ..., "command": ...,
"robot": ..., "results": [row, ...]}`` (docs/design.md §7; ``ratio_to_mink`` of a row is against
``mink-native``), plus ``correctness`` (every HQP backend against the stored lexicographic
reference, :mod:`compare.bench.correctness`) when that group ran. The profiles of the project's
own loop (the plant alone, the loop's parts) are scripts: ``scripts/plant_bench.py`` and
``scripts/loop_parts.py`` (docs/benchmarks.md).
"""

from __future__ import annotations

import json
import math
import shlex
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

import pandas as pd
from rich.console import Console
from rich.table import Table

from compare.analysis.metric import to_jsonable
from compare.bench.correctness import HQP_BACKENDS, TOLERANCE, StepRecord, Summary, run_correctness_bench, summarize
from compare.bench.correctness_plot import plot_time_vs_correctness
from compare.bench.qp_export import collect_bench_qps, export_test_set
from compare.bench.qp_reference import REFERENCE_FILE, ReferenceMismatch, load_reference
from compare.bench.sensing import run_sensing_bench
from compare.bench.solvers import DEFAULT_METHODS, run_candidate_bench, run_solver_bench
from compare.bench.timing import BenchRow
from compare.config import Config, load_config
from compare.exceptions import CompareError
from compare.versions import versions
from robots import DEFAULT_ROBOT

GROUPS = ("solvers", "sensing", "correctness")
"""The benchmark groups, in the order a full run makes them (``only`` picks one)."""

LABELS = {"mink": "mink (project adapter)", "mink-native": "mink-native (reference)"}
"""Table labels; the JSON keeps the method names."""


_FLAGS = {"json_out": "--json"}
"""Options whose flag is not their field's name (the others: ``--<name-with-dashes>``)."""


class BenchError(CompareError, ValueError):
    """An option out of its range, or a group that cannot run with the files given (one line, exit 2)."""


@dataclass(frozen=True)
class BenchOptions:
    """What ``tpik-compare bench`` runs; every field is the option of the same name.

    Attributes:
        only: One group of :data:`GROUPS`; None = all.
        methods: Solvers group: the methods of the case-2 table.
        repeats: Timed calls per method and case.
        json_out: Write the results as JSON to this file (``--json``).
        config: Scenario TOML whose robot, levels (the case-2 hierarchy) and method settings are
            used; None = the paper's case 2 on the default robot.
        max_candidates: Largest |C| of the TPIK-vs-candidates table, 0..12; −1 skips it.
        backends: Correctness: the HQP methods judged against the reference.
        rounds: Correctness: timed passes over the reference states.
        tolerance: Correctness: level error within which a level matches the reference.
        plot: Correctness: write the time-vs-correctness figure (PNG/SVG).
        csv: Correctness: one row per (state, backend): qpbenchmark's residual columns and both verdicts.
        export_qps: Correctness: write the level QPs of the reference states as a qpbenchmark test set.
        export_method: The HQP method whose cascade poses the exported QPs.

    Raises:
        BenchError: An option out of its range (naming it).
    """

    only: str | None = None
    methods: tuple[str, ...] = tuple(DEFAULT_METHODS)
    repeats: int = 300
    json_out: Path | None = None
    config: Path | None = None
    max_candidates: int = 8
    backends: tuple[str, ...] = HQP_BACKENDS
    rounds: int = 3
    tolerance: float = TOLERANCE
    plot: Path | None = None
    csv: Path | None = None
    export_qps: Path | None = None
    export_method: str = "hqp-piqp"

    def __post_init__(self) -> None:
        if self.only is not None and self.only not in GROUPS:
            raise BenchError(f"--only must be {', '.join(GROUPS[:-1])} or {GROUPS[-1]}, got '{self.only}'")
        if self.repeats < 1:
            raise BenchError(f"--repeats must be >= 1, got {self.repeats}")
        if not -1 <= self.max_candidates <= 12:
            raise BenchError(f"--max-candidates must be in -1..12, got {self.max_candidates}")
        if self.rounds < 1:
            raise BenchError(f"--rounds must be >= 1, got {self.rounds}")
        if not (math.isfinite(self.tolerance) and self.tolerance > 0):
            raise BenchError(f"--tolerance must be a finite number > 0, got {self.tolerance}")
        bad = [b for b in self.backends if not b.startswith("hqp-")]
        if bad:
            raise BenchError(f"--backends takes hqp-<backend> methods only, got {', '.join(bad)}")
        if not self.export_method.startswith("hqp-"):
            raise BenchError(f"--export-method must be an hqp-<backend> method, got '{self.export_method}'")
        if not (self.methods and self.backends):
            raise BenchError("--methods and --backends need at least one value")

    def runs(self, group: str) -> bool:
        """Whether ``group`` is part of this run."""
        return self.only in (None, group)

    def command(self) -> str:
        """The ``tpik-compare bench`` command line of these options (defaults left out)."""
        words = ["tpik-compare", "bench"]
        for f in fields(self):
            value = getattr(self, f.name)
            if value == f.default:
                continue
            flag = _FLAGS.get(f.name, "--" + f.name.replace("_", "-"))
            for item in value if isinstance(value, tuple) else (value,):
                words += [flag, str(item)]
        return shlex.join(words)


def _fmt(value: float | None, digits: int = 1) -> str:
    return "" if value is None else f"{value:.{digits}f}"


RATIO_CAPTION = (
    "× mink = whole step / mink-native's whole step, timed in the same interleaved run: mostly compiled code or"
    " our Python against mink's Python layer (its build_ik, the row updates), not one algorithm against another."
    " Split of the same calls (medians): core = the QP solver (mink, HQP: every backend call) or TPIK's compiled"
    " step (its kinematics, rows, mode search); build = mink.build_ik, HQP's assembly, TPIK's Python part; rows ="
    " mink's kinematics and row updates; rest = the call minus those. core × mink compares the cores alone."
)
"""The sentence under every "× mink" table: what the ratios compare (:mod:`compare.bench.solvers`)."""


def solver_table(rows: list[BenchRow], title: str) -> Table:
    """Rich table of solver rows: median, p95, ratio to mink-native, the core/build/rows/rest split."""
    table = Table(title=title, caption=RATIO_CAPTION)
    for col, justify in (
        ("method", "left"),
        ("case", "left"),
        ("median [µs]", "right"),
        ("p95 [µs]", "right"),
        ("× mink (native)", "right"),
        ("core [µs]", "right"),
        ("core × mink", "right"),
        ("build [µs]", "right"),
        ("rows [µs]", "right"),
        ("rest [µs]", "right"),
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
            _fmt(e.get("core_us")),
            _fmt(e.get("core_ratio_to_mink"), 2),
            _fmt(e.get("build_us")),
            _fmt(e.get("rows_us") or None),
            _fmt(e.get("rest_us")),
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
    """Rich table of :class:`~compare.bench.correctness.Summary` rows: both verdicts side by side.

    "lexicographic" judges the command against the reference cascade (the project's test, with the
    Wilson 95 % interval of its rate); "qpbenchmark" judges the level QPs by qpbenchmark's criterion
    (primal residual, dual residual and duality gap below its tolerance), beside the worst
    residuals and gap over the steps.
    """
    table = Table(title=title)
    for col in (
        "backend",
        "states",
        "lexicographic correct",
        "95 % CI [%]",
        "flagged",
        "silent",
        "worst e_k",
        "qpbenchmark solved",  # its tolerance: correctness_legend, printed below the table
        "worst primal",
        "worst dual",
        "worst gap",
        "median µs",
        "p95 µs",
        "QPs per step",
    ):
        left = col in ("backend", "states")
        table.add_column(col, justify="left" if left else "right", no_wrap=left)

    def sci(quantiles: dict[str, Any]) -> str:
        value = quantiles.get("max")
        if value is None and quantiles.get("non_finite"):
            return "inf"  # read back from JSON, where an infinite value is null
        if value is None or math.isnan(value):
            return ""
        return "inf" if math.isinf(value) else f"{value:.1e}"

    def percent(rate: dict[str, Any]) -> str:
        return "" if not rate or not rate["runs"] else f"{100 * rate['rate']:.1f} %"

    for s in summaries:
        lo, hi = s.success_rate["ci95"]
        table.add_row(
            s.name,
            f"{s.states} ({s.count})",
            str(s.correct),
            f"{100 * lo:.3g}–{100 * hi:.3g}",
            str(s.flagged),
            str(s.silent),
            f"{s.worst_level_error:.1e}",
            percent(s.qpbenchmark_success),
            sci(s.primal_residual),
            sci(s.dual_residual),
            sci(s.duality_gap),
            _fmt(s.time_us.get("median")),
            _fmt(s.time_us.get("p95")),
            f"{s.qp_calls_per_step:.2f}",
        )
    return table


def correctness_legend(summaries: list[Summary]) -> str:
    """What the two verdicts of :func:`correctness_table` are, printed below it."""
    tol = summaries[0].qpbenchmark_tolerance if summaries else 0.0
    return (
        "lexicographic correct: the command matches or beats the reference cascade, level by level "
        "(the project's test; 95 % CI: Wilson interval of its rate). qpbenchmark solved: every level QP "
        f"of the step has primal residual, dual residual and duality gap below {tol:g} (qpbenchmark's "
        "criterion); worst: the largest over the steps."
    )


def _write_records_csv(records: list[StepRecord], path: Path) -> None:
    """One row per (state, backend) with qpbenchmark's column names where they apply, and both verdicts.

    ``problem`` is the state and ``runtime`` the whole control step [s] (kinematics, every level
    QP, the certificate), not one QP as in qpbenchmark's results; the residuals are the worst of
    the step's level QPs; ``qpbenchmark_solved`` is qpbenchmark's criterion on them
    (:data:`~compare.bench.correctness.QPBENCHMARK_TOLERANCE`), ``verdict`` the lexicographic one.
    """
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
            "qpbenchmark_solved": r.qpbenchmark_solved(),
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


def _run_correctness(options: BenchOptions, console: Console) -> dict[str, Any]:
    """The correctness group: its table, figure, CSV and QP export; its ``correctness`` JSON entry."""
    try:
        entries = load_reference()
    except (FileNotFoundError, ReferenceMismatch) as exc:
        raise BenchError(f"correctness bench: {exc}") from exc
    records = run_correctness_bench(list(options.backends), entries, rounds=options.rounds, tol=options.tolerance)
    summaries = summarize(records)
    console.print(
        correctness_table(
            summaries,
            "Timing vs correctness: HQP backends vs the lexicographic reference "
            f"(tolerance {options.tolerance:g}, {options.rounds} interleaved rounds)",
        )
    )
    console.print(correctness_legend(summaries))
    if options.plot is not None:
        console.print(f"wrote {plot_time_vs_correctness(summaries, records, options.plot, options.tolerance)}")
    if options.csv is not None:
        _write_records_csv(records, options.csv)
        console.print(f"wrote {options.csv}")
    if options.export_qps is not None:
        export = export_test_set(
            collect_bench_qps(options.export_method, entries), options.export_qps, options.command()
        )
        console.print(
            f"wrote {len(export.problems)} hard level QPs (of {len(export.candidates)} candidates) "
            f"posed by {options.export_method} to {options.export_qps}"
        )
    data = json.loads(REFERENCE_FILE.read_text(encoding="utf-8"))
    return {
        "tolerance": options.tolerance,
        "rounds": options.rounds,
        "reference": {"file": REFERENCE_FILE.name, "fingerprint": data["fingerprint"], "made_with": data["made_with"]},
        "summaries": [to_jsonable(s.to_dict()) for s in summaries],
    }


def _run_solvers(options: BenchOptions, config: Config | None, console: Console) -> list[BenchRow]:
    """The case-2 table (the robot, levels and settings of ``config`` when given) and the TPIK-vs-|C| table."""
    robot, description, settings = None, None, None
    if config is not None:
        robot, description, settings = config.load_robot(), config.hierarchy_description(), config.methods.settings
    rows = run_solver_bench(list(options.methods), options.repeats, robot, description, settings)
    where = f"{options.config} ({robot.name})" if robot is not None else "case-2 hierarchy"
    console.print(solver_table(rows, f"Solvers, {where}: one step incl. kinematics"))
    if options.max_candidates >= 0:
        candidates = run_candidate_bench(options.repeats, options.max_candidates, robot=robot)
        console.print(solver_table(candidates, "TPIK vs number of candidate set tasks |C|"))
        rows += candidates
    return rows


def run_bench(options: BenchOptions) -> dict[str, Any]:
    """Run the groups of ``options``, print their tables; write and return the JSON payload.

    Raises:
        BenchError: A group cannot run with the files given (a missing reference).
        compare.config.ConfigError: A config file is invalid.
    """
    config = load_config(options.config)[0] if options.config is not None else None  # refused before any timing
    console = Console(width=max(Console().width, 200))
    info = versions()
    console.print(
        f"python {info.get('python')} · numpy {info.get('numpy')} · pin {info.get('pin')} · "
        f"mujoco {info.get('mujoco')} · mink {info.get('mink')} · cpu {info.get('cpu')} ({info.get('machine')})"
    )
    robot = config.load_robot() if config is not None else None
    payload: dict[str, Any] = {
        "versions": info,
        "command": options.command(),
        "robot": robot.name if robot is not None else DEFAULT_ROBOT,
        "results": [],
    }
    rows: list[BenchRow] = []
    if options.runs("solvers"):
        rows += _run_solvers(options, config, console)
    if options.runs("sensing"):
        sensing = run_sensing_bench(options.repeats, robot)
        console.print(_generic_table(sensing, "Sensing, one 512×424 frame"))
        rows += sensing
    if options.runs("correctness"):
        payload["correctness"] = _run_correctness(options, console)
    payload["results"] = [r.to_dict() for r in rows]
    if options.json_out is not None:
        options.json_out.parent.mkdir(parents=True, exist_ok=True)
        options.json_out.write_text(json.dumps(payload, indent=2) + "\n", encoding="utf-8")
        console.print(f"wrote {options.json_out}")
    return payload


__all__ = [
    "GROUPS",
    "RATIO_CAPTION",
    "BenchError",
    "BenchOptions",
    "correctness_table",
    "run_bench",
    "solver_table",
]

r"""Where a campaign step goes: the closed loop's parts timed one by one (a profile of the project itself).

Run from the repository root::

    python scripts/loop_parts.py        # configs/random.toml; tpik, hqp-daqp, mink; seeds 100001-100003
    python scripts/loop_parts.py -m tpik --seed 100001 --family configs/random.toml --json results/loop_parts.json

:func:`run_loop_parts` runs whole runs of one scenario family, one method at a time, in this
process (a sweep worker's steady state: one untimed run first loads the kernels and builds the
caches), with a timer around each named part of the loop (:data:`PARTS`: the plant, the
solve, sensing, the ground truth, recording, ...). Each part is charged its *exclusive* time:
the time inside it minus the time inside the parts it calls, so the parts add up to the whole
run and nothing is counted twice,

.. math::

    t_{excl}(p) = \sum_{\text{calls of } p} (t_{end} - t_{start})
                - \sum_{\text{timed calls } c \text{ inside them}} (t_{end}(c) - t_{start}(c)),

reported per control step (the run's time divided by its steps). The method's own solve comes
from the run's per-step table (``solve_time_us``, what the loop records) and is taken out of
the timed solve's row, which keeps the loop's bookkeeping around the call.

``--clock cpu`` times every part on the thread's CPU clock instead of the wall clock (on a
machine shared with other processes, a wall-clock part also counts the time the process waited
for a core); the method's own solve is then timed by a timer on the methods' ``solve``
(:data:`SOLVE_PARTS`), its warm-up solves included (3 per run of some 2000 steps).

The timers cost time themselves (:func:`wrapper_cost_ns`, measured here on a no-op part): the
table says how many timed calls a step makes and what they cost, and beside it the same runs'
CPU time per step with no timer installed (process CPU time, the figure a sweep is judged on).
Timers are installed by replacing the named attributes for the duration of the call and are
always restored.

``--stand-in`` replaces the plant, the method's solve or both for the runs (:func:`stand_ins`):
a control period then only advances the simulated clock, a solve answers a zero velocity. What is
left is the loop's own code with nothing run between its steps; beside the same figure with the
real plant and solve it shows how much of the shared loop's cost is theirs (their work evicts the
loop's code and data from the caches). Such runs are not campaign runs: the arm and the person
stand still.
"""

from __future__ import annotations

import functools
import importlib
import json
import sys
import tempfile
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from rich.console import Console
from rich.table import Table

import compare.run
from compare.analysis.results import load_steps
from compare.arguments import ArgumentParser, existing_file, output_path
from compare.bench.timing import BenchRow, summarize
from compare.campaign.sweep import seeded_config
from compare.config import Config, load_config
from compare.exceptions import CompareError
from compare.loop import closed_loop
from compare.loop.sim_io import SimRobotIO
from compare.versions import versions
from robots import Kinematics
from tpik.hierarchy import Hierarchy
from tpik.step_result import IkSolver, SolveStatus

RANDOM_CONFIG = Path(__file__).resolve().parents[1] / "configs" / "random.toml"
"""The scenario family timed by default (the reference campaign's)."""

METHODS = ("tpik", "hqp-daqp", "mink")
"""The reference campaign's methods: the default, each alone in its runs."""

SEEDS = (100001, 100002, 100003)
"""Seeds of the timed runs by default (of the reference campaign's 100000–100999)."""


@dataclass(frozen=True)
class Part:
    """One timed part of the loop: ``attribute`` (``name`` or ``Class.name``) of ``module``.

    Attributes:
        label: Row of the table.
        module: Module that holds the attribute the loop calls (for a function imported by name,
            the module that calls it).
        attribute: ``function`` or ``Class.method``.
        returns_callable: The attribute builds the callable the loop calls (time that instead).
    """

    label: str
    module: str
    attribute: str
    returns_callable: bool = False


RUN_PART = "per run: scenario, results files"
"""The label of the outermost part (a whole run): its inclusive times are the runs' whole time."""

GUARD_PART = "timed solve (the method's own call taken out below)"
"""The label of the timed solve, whose row keeps all but the method's own call (:data:`OWN_SOLVE`)."""

STEP_PART = "the step's own code"
"""The label whose calls are the control steps (their inclusive times give the step's median)."""

PLANT_PART = "plant (person, drive, MuJoCo sub-steps)"
"""The label of the simulated plant (what a step costs besides the loop and the method)."""

TRUTH_PART = "ground-truth distance (kept a step, computed at the end)"
"""The label of the ground truth: what a step keeps of it and its computation at the run's end."""

PARTS: tuple[Part, ...] = (
    Part(PLANT_PART, "compare.loop.sim_io", "SimRobotIO.wait"),
    Part(GUARD_PART, "compare.loop.closed_loop", "timed_solve"),
    Part("kinematics snapshot", "robots.robot", "Robot.kinematics"),
    Part("kinematics snapshot", "robots.robot", "Robot.renew"),
    Part("sensing gate (obstacle source, ISO/TS 15066 monitor)", "compare.loop.sensing_gate", "SensingGate.step"),
    Part(TRUTH_PART, "compare.sensing.ground_truth", "GroundTruth.record"),
    Part(TRUTH_PART, "compare.sensing.ground_truth", "GroundTruth.recorded"),
    Part("fallback policy", "compare.loop.fallback", "FallbackPolicy.decide"),
    Part("waypoints", "compare.loop.waypoints", "WaypointSchedule.update"),
    Part("joint reading, command, clock", "compare.loop.sim_io", "SimRobotIO.read_joints"),
    Part("joint reading, command, clock", "compare.loop.sim_io", "SimRobotIO.send_velocity"),
    Part("joint reading, command, clock", "compare.loop.sim_io", "SimRobotIO.now"),
    Part("σ of every set task, rows of those past activation", "compare.loop.set_task_watch", "SetTaskWatch.measure"),
    Part("status check (set-task reference rates)", "compare.loop.set_task_watch", "SetTaskWatch.unmet"),
    Part("motion, σ, flags, status, distances recorded", "compare.loop.recorder", "StepRecorder.motion"),
    Part("motion, σ, flags, status, distances recorded", "compare.loop.recorder", "StepRecorder.set_tasks"),
    Part("motion, σ, flags, status, distances recorded", "compare.loop.recorder", "StepRecorder.outcome"),
    Part("motion, σ, flags, status, distances recorded", "compare.loop.recorder", "StepRecorder.distances"),
    Part(STEP_PART, "compare.loop.closed_loop", "_Step.run"),
    Part("the loop around the steps", "compare.run", "run_loop"),
    Part("per run: method set-up, warm-up, summary", "compare.run", "run_method"),
    Part(RUN_PART, "compare.run", "run_scenario"),
)
"""The parts, in table order; parts with the same label are added up."""

OWN_SOLVE = "the method's own solve"
"""The row of the method's own call, taken out of the timed solve's."""

SOLVE_PARTS: tuple[Part, ...] = (
    Part(OWN_SOLVE, "tpik.solver", "TpikSolver.solve"),
    Part(OWN_SOLVE, "qp_baseline.hqp", "HqpSolver.solve"),
    Part(OWN_SOLVE, "qp_baseline.mink_peer", "MinkSolver.solve"),
)
"""On the CPU clock: the methods' own ``solve``, timed where the loop calls it."""

STAND_INS = ("plant", "solve", "both")
"""What ``--stand-in`` can replace (:func:`stand_ins`)."""

CLOCKS = {"wall": "perf_counter_ns", "cpu": "thread_time_ns"}
"""What a part is timed on: the name of the ``time`` function [ns] (read when a timer is made)."""


@dataclass
class _Tally:
    calls: int = 0
    exclusive_ns: int = 0
    inclusive_ns: list[int] = field(default_factory=list)


class PartProfiler:
    """Exclusive time per labelled part (module docstring); nested timed calls are subtracted."""

    def __init__(self, keep_inclusive: Sequence[str] = (), clock: str = "wall") -> None:
        self.tallies: dict[str, _Tally] = {}
        self._children = [0]  # time inside timed parts, per open timed call (outermost: unused)
        self._keep = set(keep_inclusive)
        self.clock = clock

    def wrap(self, label: str, fn: Callable[..., Any]) -> Callable[..., Any]:
        """``fn`` with its calls charged to ``label``."""
        tally = self.tallies.setdefault(label, _Tally())
        children, clock = self._children, getattr(time, CLOCKS[self.clock])
        inclusive = tally.inclusive_ns if label in self._keep else None

        @functools.wraps(fn)
        def timed(*args: Any, **kwargs: Any) -> Any:
            children.append(0)
            t0 = clock()
            try:
                return fn(*args, **kwargs)
            finally:
                elapsed = clock() - t0
                tally.calls += 1
                tally.exclusive_ns += elapsed - children.pop()
                children[-1] += elapsed
                if inclusive is not None:
                    inclusive.append(elapsed)

        return timed

    def wrap_factory(self, label: str, factory: Callable[..., Any]) -> Callable[..., Any]:
        """``factory`` whose returned callable is charged to ``label`` (building it is not)."""

        @functools.wraps(factory)
        def build(*args: Any, **kwargs: Any) -> Any:
            return self.wrap(label, factory(*args, **kwargs))

        return build


def _owner(part: Part) -> tuple[Any, str]:
    obj: Any = importlib.import_module(part.module)
    *path, name = part.attribute.split(".")
    for attr in path:
        obj = getattr(obj, attr)
    return obj, name


def check_parts(parts: Sequence[Part] = PARTS) -> None:
    """Raise ``AttributeError`` naming a part whose attribute no longer exists (a renamed loop part)."""
    for part in parts:
        owner, name = _owner(part)
        if not callable(getattr(owner, name, None)):
            raise AttributeError(f"loop part {part.label!r}: {part.module}.{part.attribute} is not a callable")


@contextmanager
def timers(profiler: PartProfiler, parts: Sequence[Part] = PARTS) -> Iterator[None]:
    """Install a timer on every part for the duration of the block; the originals are restored."""
    check_parts(parts)
    saved: list[tuple[Any, str, Any]] = []
    try:
        for part in parts:
            owner, name = _owner(part)
            fn = getattr(owner, name)
            timed = profiler.wrap_factory(part.label, fn) if part.returns_callable else profiler.wrap(part.label, fn)
            _replace(owner, name, timed, saved)
        yield
    finally:
        _restore(saved)


def _replace(owner: Any, name: str, new: Any, saved: list[tuple[Any, str, Any]]) -> None:
    """Set ``owner.name`` to ``new``, its original (a class's own attribute) kept in ``saved`` first."""
    saved.append((owner, name, owner.__dict__[name] if isinstance(owner, type) else getattr(owner, name)))
    setattr(owner, name, new)


def _restore(saved: list[tuple[Any, str, Any]]) -> None:
    """Put back what :func:`_replace` replaced, the last replacement first."""
    for owner, name, original in reversed(saved):
        setattr(owner, name, original)


def _clock_only_period(io: SimRobotIO) -> None:
    """A control period of the stand-in plant: the simulated clock advances, nothing moves."""
    io.data.time += io.dt


def _zero_solve(
    solver: IkSolver, hierarchy: Hierarchy, kin: Kinematics, dt: float
) -> tuple[np.ndarray, SolveStatus, tuple[str, ...], str, bool, float]:
    """The stand-in solve: zero velocity, OK, no active task, no time (the method is not called)."""
    return np.zeros(kin.nq), SolveStatus.OK, (), "", False, 0.0


@contextmanager
def stand_ins(kind: str | None) -> Iterator[None]:
    """The plant (``plant``), the loop's timed solve (``solve``) or both replaced for the block; None: neither.

    The stand-ins are :func:`_clock_only_period` for ``SimRobotIO.wait`` and :func:`_zero_solve`
    for ``compare.loop.closed_loop.timed_solve``; the originals are always restored.
    """
    if kind is not None and kind not in STAND_INS:
        raise ValueError(f"stand-in must be one of {', '.join(STAND_INS)}, got {kind!r}")
    saved: list[tuple[Any, str, Any]] = []
    try:
        if kind in ("plant", "both"):
            _replace(SimRobotIO, "wait", _clock_only_period, saved)
        if kind in ("solve", "both"):
            _replace(closed_loop, "timed_solve", _zero_solve, saved)
        yield
    finally:
        _restore(saved)


def wrapper_cost_ns(calls: int = 20_000, clock: str = "wall") -> float:
    """What one timed call adds to a run [ns]: a no-op part inside a timed parent, against the bare loop."""

    def noop() -> None:
        return None

    def loop(fn: Callable[[], None]) -> None:
        for _ in range(calls):
            fn()

    samples = []
    for _ in range(5):
        profiler = PartProfiler(clock=clock)
        child, parent = profiler.wrap("child", noop), profiler.wrap("parent", loop)
        t0 = time.perf_counter_ns()
        loop(noop)
        bare = time.perf_counter_ns() - t0
        t0 = time.perf_counter_ns()
        parent(child)
        timed = time.perf_counter_ns() - t0
        samples.append((timed - bare) / calls)
    return float(np.median(samples))


@dataclass(frozen=True)
class LoopParts:
    """One method's loop parts over the timed runs.

    Attributes:
        method: The method.
        parts_us: Exclusive time per control step by part [µs] (table order; the method's own
            solve in :data:`OWN_SOLVE`, out of the timed solve's row).
        steps: Control steps of the timed runs.
        timed_calls_per_step: Timer calls per step (per-run parts spread over the steps).
        step_us: Inclusive time of each control step, the plant not included [µs].
        unprofiled_cpu_us_per_step: Process CPU time per step of the same runs with no timer [µs].
        runs_us_per_step: The timed runs' whole time per step [µs] (what the parts add up to).
    """

    method: str
    parts_us: dict[str, float]
    steps: int
    timed_calls_per_step: float
    step_us: np.ndarray
    unprofiled_cpu_us_per_step: float
    runs_us_per_step: float

    @property
    def total_us(self) -> float:
        """Sum of the parts per step [µs] (the profiled runs' whole time)."""
        return float(sum(self.parts_us.values()))

    def shared_loop_us(self, timer_cost_us: float) -> float:
        """What the shared loop costs per step [µs]: the profiled total without plant, own solve and timers."""
        return self.total_us - self.parts_us[PLANT_PART] - self.parts_us[OWN_SOLVE] - timer_cost_us

    @property
    def unprofiled_shared_loop_us(self) -> float:
        """The CPU per step without timers, less the plant and the own solve as profiled [µs]."""
        return self.unprofiled_cpu_us_per_step - self.parts_us[PLANT_PART] - self.parts_us[OWN_SOLVE]


def _own_solve_us(out_dir: Path, method: str) -> float:
    return float(load_steps(out_dir, method, columns=["solve_time_us"])["solve_time_us"].sum())


class LoopRunFailed(CompareError):
    """A run timed by :func:`run_loop_parts` ended in an error of its method (nothing to time)."""


def _run(config: Config, out: Path) -> None:
    # Looked up on the module at each call: the timed run reaches the timer put on it.
    summary = compare.run.run_scenario(config, out, progress=False, make_plots=False, overwrite=True, report=False)
    errors = summary.get("errors") or {}
    if errors:
        what = "; ".join(f"{m}: {e}" for m, e in errors.items())
        raise LoopRunFailed(f"the run of seed {config.scenario.seed} failed ({what})")


def run_loop_parts(
    config: Config, method: str, seeds: Sequence[int], clock: str = "wall", stand_in: str | None = None
) -> LoopParts:
    """Time the loop's parts on runs of ``config`` with ``method`` alone (module docstring).

    Args:
        config: A scenario or a ``kind = "random"`` family.
        method: The method driving the arm.
        seeds: Scenario seeds of the timed runs; one untimed run of the first seed comes before.
        clock: ``wall`` or ``cpu`` (:data:`CLOCKS`).
        stand_in: Replace the plant, the solve or both in every run (:func:`stand_ins`); None: neither.

    Returns:
        :class:`LoopParts` of the timed runs.

    Raises:
        LoopRunFailed: A run's method ended in an error.
    """
    configs = [seeded_config(config, int(s), [method]) for s in seeds]
    with tempfile.TemporaryDirectory(prefix="loop-parts-") as tmp, stand_ins(stand_in):
        root = Path(tmp)
        _run(configs[0], root / "warm")
        cpu = 0.0
        profiler = PartProfiler(keep_inclusive=(STEP_PART, RUN_PART), clock=clock)
        timed_parts = PARTS + SOLVE_PARTS if clock == "cpu" else PARTS
        own_solve_us = 0.0
        for k, cfg in enumerate(configs):  # each seed unprofiled (the CPU a sweep worker spends), then timed
            t0 = time.process_time()
            _run(cfg, root / f"plain{k}")
            cpu += time.process_time() - t0
            with timers(profiler, timed_parts):
                _run(cfg, root / f"timed{k}")
            own_solve_us += _own_solve_us(root / f"timed{k}", method)
    step_tally = profiler.tallies[STEP_PART]
    steps = step_tally.calls
    parts: dict[str, float] = {}
    for label in dict.fromkeys(p.label for p in PARTS):  # table order, each label once
        parts[label] = profiler.tallies[label].exclusive_ns * 1e-3 / steps
        if label == GUARD_PART and clock == "cpu":  # timed apart: already out of this row
            parts[OWN_SOLVE] = profiler.tallies[OWN_SOLVE].exclusive_ns * 1e-3 / steps
        elif label == GUARD_PART:
            parts[OWN_SOLVE] = own_solve_us / steps
            parts[label] -= own_solve_us / steps
    calls = sum(t.calls for t in profiler.tallies.values())
    return LoopParts(
        method,
        parts,
        steps,
        calls / steps,
        np.asarray(step_tally.inclusive_ns, dtype=float) * 1e-3,
        cpu * 1e6 / steps,
        sum(profiler.tallies[RUN_PART].inclusive_ns) * 1e-3 / steps,
    )


def loop_parts_rows(results: Sequence[LoopParts], cost_ns: float) -> tuple[list[BenchRow], dict[str, Any]]:
    """The JSON rows and the ``loop_parts`` entry of the methods' loop parts.

    Rows: name ``loop-step``, case the method, the inclusive time of a step without the plant.
    Entry: per method, its parts, totals and the timers' cost.
    """
    rows = [
        summarize(
            "loop-step",
            r.method,
            r.step_us,
            total_us_per_step=r.total_us,
            unprofiled_cpu_us_per_step=r.unprofiled_cpu_us_per_step,
        )
        for r in results
    ]
    entry: dict[str, Any] = {
        "timer_cost_ns": cost_ns,
        "methods": {
            r.method: {
                "steps": r.steps,
                "parts_us_per_step": r.parts_us,
                "total_us_per_step": r.total_us,
                "timed_calls_per_step": r.timed_calls_per_step,
                "timer_cost_us_per_step": r.timed_calls_per_step * cost_ns * 1e-3,
                "unprofiled_cpu_us_per_step": r.unprofiled_cpu_us_per_step,
                "shared_loop_us_per_step": r.shared_loop_us(r.timed_calls_per_step * cost_ns * 1e-3),
                "unprofiled_shared_loop_us_per_step": r.unprofiled_shared_loop_us,
            }
            for r in results
        },
    }
    return rows, entry


def loop_parts_table(results: Sequence[LoopParts], entry: dict[str, Any], cost_ns: float, title: str) -> Table:
    """The parts per method as a table [µs per step]: exclusive times, their total, the timers, the CPU without them."""
    table = Table(title=title)
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
    table.add_row(
        "[bold]shared loop: total − plant − own solve − timers",
        *(f"[bold]{per_method[r.method]['shared_loop_us_per_step']:.1f}" for r in results),
    )
    table.add_row(
        "  the same from the CPU per step, no timer",
        *(f"{r.unprofiled_shared_loop_us:.1f}" for r in results),
    )
    return table


def main(argv: Sequence[str] | None = None) -> int:
    """Time the loop's parts of every method given; print the table, write ``--json``; the exit code."""
    parser = ArgumentParser(
        prog="python scripts/loop_parts.py",
        description=__doc__.splitlines()[0] + "\n\nPrints each part's exclusive time per control step [µs] "
        "per method (whole runs, one method\nat a time, in this process).",
    )
    parser.add_argument(
        "--family",
        type=existing_file,
        default=RANDOM_CONFIG,
        metavar="TOML",
        help="scenario family (default: configs/random.toml)",
    )
    parser.add_argument(
        "-m",
        "--method",
        action="append",
        dest="methods",
        metavar="METHOD",
        help=f"a method, alone in its runs; repeatable (default: {' '.join(METHODS)})",
    )
    parser.add_argument(
        "--seed",
        action="append",
        type=int,
        dest="seeds",
        metavar="SEED",
        help=f"seed of a timed run; repeatable (default: {' '.join(map(str, SEEDS))})",
    )
    parser.add_argument("--clock", choices=tuple(CLOCKS), default="wall", help="what the parts are timed on")
    parser.add_argument(
        "--stand-in",
        choices=STAND_INS,
        help="replace the plant, the solve or both: the loop's own code alone (not a campaign run)",
    )
    parser.add_argument(
        "--json", type=output_path, dest="json_out", metavar="FILE", help="write the rows and the parts as JSON"
    )
    args = parser.parse_args(argv)
    methods, seeds = tuple(args.methods or METHODS), tuple(args.seeds or SEEDS)
    try:
        config, _ = load_config(args.family)
        seeded_config(config, seeds[0], list(methods))  # the methods checked before any run
        cost_ns = wrapper_cost_ns(clock=args.clock)
        console = Console(width=max(Console().width, 160))
        results = []
        for method in methods:
            console.print(f"loop parts: {method}, seeds {' '.join(map(str, seeds))} ({args.family}) …")
            try:
                results.append(run_loop_parts(config, method, list(seeds), args.clock, args.stand_in))
            except LoopRunFailed as exc:
                raise LoopRunFailed(f"loop parts of {method}: {exc}") from exc
    except CompareError as exc:  # a config, a method or a run that failed: one line
        print(f"error: {exc}", file=sys.stderr)
        return 2
    rows, entry = loop_parts_rows(results, cost_ns)
    entry["config"] = str(args.family)
    entry["seeds"] = list(seeds)
    entry["clock"] = args.clock
    entry["stand_in"] = args.stand_in
    replaced = f"; stand-in {args.stand_in}" if args.stand_in else ""
    title = (
        f"Where a control step goes [µs per step, exclusive, {args.clock} clock] "
        f"({args.family.name}, one method per run{replaced})"
    )
    console.print(loop_parts_table(results, entry, cost_ns, title))
    if args.json_out is not None:
        payload = {
            "versions": versions(),
            "command": " ".join(["python", "scripts/loop_parts.py", *(argv if argv is not None else sys.argv[1:])]),
            "results": [r.to_dict() for r in rows],
            "loop_parts": entry,
        }
        args.json_out.parent.mkdir(parents=True, exist_ok=True)
        args.json_out.write_text(json.dumps(payload, indent=2) + "\n", encoding="utf-8")
        console.print(f"wrote {args.json_out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

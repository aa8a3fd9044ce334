r"""Re-time the deadline misses of a sweep: the method's cost at that state, or the machine's pause?

A deadline miss (docs/design.md §3: a solve over the time limit, after warm-up) is measured on the
solving thread's CPU clock. On a virtual machine that clock also runs while the hypervisor holds
the virtual CPU without counting it as steal (``docs/benchmarks.md``, "Deadline misses and the
VM's CPU clock"): such a pause lands on whatever code runs, and a solve it lands on reads as late
although its own work was a fraction of the limit. Whether a miss belongs to the method or to
the machine is decided here by measuring the method's cost at exactly that state again.

For every missed step :math:`i` of a (run, method):

1. the run is simulated again from its seed, with the same code, configuration and time limit;
   the misses recorded before step :math:`i` are made misses again (the method still solves
   them, as it did, and its answer is discarded), so the loop, which is deterministic otherwise,
   meets the same state at step :math:`i`, unless the rerun has a late call of its own before
   it (then the joint state at step :math:`i` differs from the recorded one, and the miss is
   *unverified*);
2. at step :math:`i`, before the guarded call, the method and the hierarchy are deep-copied
   :math:`R` times (the robot model and the guard's clock are shared); the rerun's own guarded
   call runs as in the campaign (``rerun_missed``: whether it was late again);
3. each copy then solves that step once on a fresh kinematics snapshot, timed on the thread's
   CPU clock: :math:`R` independent measurements of the method's own cost at that state;
4. the miss is *reproduced* when the median of the :math:`R` replays exceeds the limit (the
   method needs that long there), *not reproduced* when it does not (the step costs less than
   the limit: the campaign's measurement included a pause of the machine).

``tpik-compare recheck-misses SWEEP`` writes ``deadline_recheck.json`` (one entry per miss) into
the sweep directory and adds ``deadline_recheck`` per method to ``sweep_summary.json``; the sweep
report shows it beside the misses.
"""

from __future__ import annotations

import copy
import json
import logging
import statistics
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from compare.analysis.atomic_files import write_json_atomic
from compare.analysis.exceptions import ResultsError
from compare.analysis.results import (
    CONFIG_FILE,
    RUNS_DIR,
    SUMMARY_FILE,
    SWEEP_SUMMARY_FILE,
    load_steps,
    load_summary,
)
from compare.config import Config, ConfigError, load_config
from compare.loop.deadline import DeadlineGuard, MeasuredDeadline, late_result
from robots import Kinematics, Robot
from tpik.hierarchy import Hierarchy
from tpik.step_result import IkSolver, StepResult

log = logging.getLogger(__name__)

RECHECK_FILE = "deadline_recheck.json"
"""Per-miss results of :func:`recheck_sweep`, in the sweep directory."""

DEFAULT_REPLAYS = 5
"""Copies of the method timed at each missed step (the median decides)."""


@dataclass(frozen=True)
class Miss:
    """One deadline miss of one (run, method) of a sweep.

    Attributes:
        run_dir: The run's directory.
        seed: The run's seed.
        method: Method name.
        step: Row of the per-step table of the miss (the loop's step index).
        t_s: Its loop time [s].
        solve_time_us: Its recorded solve time (wall clock) [µs].
        earlier: Steps of the misses of this (run, method) before this one.
        q: Joint state recorded at that step [rad].
    """

    run_dir: Path
    seed: int
    method: str
    step: int
    t_s: float
    solve_time_us: float
    earlier: tuple[int, ...]
    q: tuple[float, ...]


@dataclass
class Recheck:
    """What re-timing one :class:`Miss` found (module docstring).

    Attributes:
        run: Run directory name.
        seed: Seed.
        method: Method name.
        step: Step index of the miss.
        t_s: Loop time of the step [s].
        limit_s: The time limit [s] (its clock: ``clock``).
        clock: ``cpu`` or ``wall``.
        recorded_us: The campaign's solve time of the step (wall clock) [µs].
        state_matches: The rerun reached the recorded joint state at that step bit for bit.
        rerun_missed: The rerun's own guarded call at that step was late too.
        replay_us: CPU time of each copy's solve at that step [µs].
        verdict: ``reproduced``, ``not_reproduced`` or ``unverified`` (state differs, or the
            rerun stopped before the step).
        earlier_misses: Misses of this (run, method) before this one (made misses again in the
            rerun, so that it follows the recorded trajectory).
        rerun_new_misses: Late calls of the rerun itself before the step (a reason for a state
            that differs; a method's budget giving up a level inside its call is another).
    """

    run: str
    seed: int
    method: str
    step: int
    t_s: float
    limit_s: float
    clock: str
    recorded_us: float
    state_matches: bool
    rerun_missed: bool | None
    replay_us: list[float] = field(default_factory=list)
    verdict: str = "unverified"
    earlier_misses: int = 0
    rerun_new_misses: int = 0


class _ProbeDone(Exception):
    """Raised by :class:`StepProbe` once the probed step is measured: the rerun stops there."""


class StepProbe:
    """Wraps the guarded solver of a rerun; measures the solves of copies at one step.

    Args:
        solver: The guarded solver (``compare.loop.deadline.MeasuredDeadline``).
        inner: The method behind the guard (what is copied and replayed).
        robot: The arm (shared by the copies, not copied).
        step: Step index to probe.
        replays: Number of copies timed.
        forced_misses: Steps before ``step`` whose answer is discarded as late, as it was in
            the recorded run (the method solves them all the same).
    """

    def __init__(
        self,
        solver: IkSolver,
        inner: IkSolver,
        robot: Robot,
        step: int,
        replays: int,
        forced_misses: Sequence[int] = (),
    ) -> None:
        self._solver, self._inner, self._robot = solver, inner, robot
        self.name = solver.name
        self.step, self.replays = int(step), int(replays)
        self.forced = frozenset(int(k) for k in forced_misses)
        self.limit_s = solver.deadline_s if isinstance(solver, DeadlineGuard) else 0.0
        self.calls = 0
        self.new_misses = 0
        """Late calls of the rerun itself before the probed step (each may have left the recorded trajectory)."""
        self.q: np.ndarray | None = None
        self.rerun_missed: bool | None = None
        self.replay_us: list[float] = []

    def __getattr__(self, name: str) -> Any:
        return getattr(self._solver, name)

    def solve(self, hierarchy: Hierarchy, kin: Kinematics, dt: float) -> StepResult:
        """The guarded solve; at the probed step also the copies' solves, then :class:`_ProbeDone`."""
        index = self.calls
        self.calls += 1
        if index != self.step:
            result = self._solver.solve(hierarchy, kin, dt)
            if index in self.forced:
                return late_result(kin.nq, self.limit_s, "no answer (a recorded miss, made again)")
            if result.deadline_miss:
                self.new_misses += 1
            return result
        # The copies share the robot and the guard's clock: a method's own time budget (the QP
        # methods') runs on that clock, started below before each replay as the guard starts it.
        clock = self._solver.steal_clock if isinstance(self._solver, MeasuredDeadline) else None
        shared: dict[int, Any] = {id(self._robot): self._robot}
        if clock is not None:
            shared[id(clock)] = clock
        copies = [copy.deepcopy((self._inner, hierarchy), dict(shared)) for _ in range(self.replays)]
        self.q = np.array(kin.q)
        result = self._solver.solve(hierarchy, kin, dt)
        self.rerun_missed = bool(result.deadline_miss)
        for solver, tasks in copies:
            fresh = self._robot.kinematics(self.q)
            if clock is not None:
                clock.begin()
            start = time.thread_time()
            try:
                solver.solve(tasks, fresh, dt)
            except Exception as exc:  # e.g. its own budget ran out: the time it took still counts
                log.debug("replay of step %d raised %s", index, exc)
            self.replay_us.append((time.thread_time() - start) * 1e6)
        raise _ProbeDone


def find_misses(sweep_dir: Path, methods: Sequence[str] | None = None) -> list[Miss]:
    """Every deadline miss of a sweep, in run and step order.

    Raises:
        ResultsError: ``sweep_dir`` is not a sweep directory.
    """
    runs_root = Path(sweep_dir) / RUNS_DIR
    if not runs_root.is_dir():
        raise ResultsError(f"{sweep_dir} is not a sweep directory (no {RUNS_DIR}/)")
    found: list[Miss] = []
    for run_dir in sorted(p for p in runs_root.iterdir() if (p / SUMMARY_FILE).exists()):
        summary = load_summary(run_dir)
        for method, entry in summary.get("methods", {}).items():
            if methods and method not in methods:
                continue
            if not isinstance(entry, dict) or not entry.get("deadline_misses"):
                continue
            steps = load_steps(run_dir, method)
            rows = [int(i) for i in np.flatnonzero(steps["deadline_miss"].to_numpy(bool))]
            q_columns = [c for c in steps.columns if c.startswith("q_")]
            q_columns.sort(key=lambda c: int(c[2:]))
            q_all = steps[q_columns].to_numpy(float)
            t_all, us_all = steps["t"].to_numpy(float), steps["solve_time_us"].to_numpy(float)
            for k, i in enumerate(rows):
                found.append(
                    Miss(
                        run_dir,
                        int(summary["seed"]),
                        method,
                        i,
                        float(t_all[i]),
                        float(us_all[i]),
                        tuple(rows[:k]),
                        tuple(float(v) for v in q_all[i]),
                    )
                )
    return found


def recheck_miss(config: Config, miss: Miss, replays: int = DEFAULT_REPLAYS) -> Recheck:
    """Rerun ``miss``'s run up to its step and time ``replays`` copies of the method there (module docstring).

    The recorded misses before it are made misses again in the rerun (:class:`StepProbe`).

    Args:
        config: The sweep's configuration (its ``config.toml``); the miss's seed is set here.
        miss: The miss to re-time.
        replays: Copies timed at the step.
    """
    from compare.campaign.sweep import seeded_config
    from compare.run import run_method
    from compare.scenarios.random_scenario import realize

    run_config = seeded_config(config, miss.seed, [miss.method])
    robot = run_config.load_robot()
    realized = realize(run_config, robot)
    limit = realized.solver_limit.limit_s(realized.scenario.dt)
    probes: list[StepProbe] = []

    def hook(guarded: IkSolver, inner: IkSolver) -> IkSolver:
        probe = StepProbe(guarded, inner, robot, miss.step, replays, miss.earlier)
        probes.append(probe)
        return probe

    try:
        run_method(realized, miss.method, robot, solver_hook=hook)
    except _ProbeDone:
        pass
    probe = probes[0] if probes else None
    out = Recheck(
        run=miss.run_dir.name,
        seed=miss.seed,
        method=miss.method,
        step=miss.step,
        t_s=miss.t_s,
        limit_s=float(limit) if limit is not None else float("nan"),
        clock=realized.solver_limit.simulation_clock,
        recorded_us=miss.solve_time_us,
        state_matches=False,
        rerun_missed=None,
        earlier_misses=len(miss.earlier),
    )
    if probe is None or probe.q is None or limit is None:
        return out  # the rerun ended before the step (or the limit is off): unverified
    out.state_matches = bool(np.array_equal(probe.q, np.array(miss.q)))
    out.rerun_missed = probe.rerun_missed
    out.rerun_new_misses = probe.new_misses
    out.replay_us = [round(v, 3) for v in probe.replay_us]
    if out.state_matches and out.replay_us:
        median_s = statistics.median(out.replay_us) * 1e-6
        out.verdict = "reproduced" if median_s > limit else "not_reproduced"
    return out


def summarize_rechecks(rechecks: Sequence[Recheck], misses_by_method: dict[str, int]) -> dict[str, dict[str, Any]]:
    """Per method: what its misses were found to be.

    Returns:
        ``{method: {"misses", "rechecked", "reproduced", "not_reproduced", "unverified",
        "not_rechecked", "replay_median_us_max"}}`` (``not_rechecked``: misses counted in the
        run summaries but not found in the step tables; the last: the largest median replay
        time over the method's rechecked misses [µs]).
    """
    out: dict[str, dict[str, Any]] = {}
    for method, total in sorted(misses_by_method.items()):
        mine = [r for r in rechecks if r.method == method]
        medians = [statistics.median(r.replay_us) for r in mine if r.replay_us]
        out[method] = {
            "misses": total,
            "rechecked": len(mine),
            "reproduced": sum(r.verdict == "reproduced" for r in mine),
            "not_reproduced": sum(r.verdict == "not_reproduced" for r in mine),
            "unverified": sum(r.verdict == "unverified" for r in mine),
            "not_rechecked": total - len(mine),
            "replay_median_us_max": round(max(medians), 3) if medians else None,
        }
    return out


def recheck_sweep(
    sweep_dir: Path,
    replays: int = DEFAULT_REPLAYS,
    methods: Sequence[str] | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> dict[str, Any]:
    """Re-time every deadline miss of a sweep; write the results (module docstring).

    Returns:
        ``{"replays", "misses": [Recheck as dict, ...], "methods": {method: summary}}``, also
        written to ``deadline_recheck.json``; ``sweep_summary.json`` gets ``deadline_recheck``
        per method (when it exists).

    Raises:
        ResultsError: Not a sweep directory, or a sweep without ``[loop] realtime`` (its
            misses changed nothing).
        ConfigError: Its ``config.toml`` is unreadable or invalid.
    """
    sweep_dir = Path(sweep_dir)
    if not (sweep_dir / CONFIG_FILE).exists():
        raise ResultsError(f"{sweep_dir} has no {CONFIG_FILE}: not a sweep directory")
    config, _ = load_config(sweep_dir / CONFIG_FILE)
    if not config.loop.realtime:
        raise ResultsError(
            f"{sweep_dir} ran without [loop] realtime: its deadline misses are reports (every answer was"
            " applied), nothing to re-time"
        )
    if replays < 1:
        raise ConfigError(f"replays must be >= 1, got {replays}")
    misses = find_misses(sweep_dir, methods)
    totals = _total_misses(sweep_dir, methods)
    rechecks: list[Recheck] = []
    for k, miss in enumerate(misses):
        rechecks.append(recheck_miss(config, miss, replays))
        if progress is not None:
            progress(k + 1, len(misses))
    result: dict[str, Any] = {
        "replays": replays,
        "rule": "reproduced: the median CPU time of the replays at the missed state exceeds the limit",
        "misses": [asdict(r) for r in rechecks],
        "methods": summarize_rechecks(rechecks, totals),
    }
    write_json_atomic(sweep_dir / RECHECK_FILE, result)
    summary_path = sweep_dir / SWEEP_SUMMARY_FILE
    if summary_path.exists():
        summary = json.loads(summary_path.read_text(encoding="utf-8"))
        for method, entry in result["methods"].items():
            summary.setdefault("methods", {}).setdefault(method, {})["deadline_recheck"] = entry
        write_json_atomic(summary_path, summary)
    return result


def _total_misses(sweep_dir: Path, methods: Sequence[str] | None) -> dict[str, int]:
    totals: dict[str, int] = {}
    for run_dir in sorted((sweep_dir / RUNS_DIR).iterdir()):
        if not (run_dir / SUMMARY_FILE).exists():
            continue
        for method, entry in load_summary(run_dir).get("methods", {}).items():
            if (methods and method not in methods) or not isinstance(entry, dict):
                continue
            totals[method] = totals.get(method, 0) + int(entry.get("deadline_misses") or 0)
    return totals

r"""The campaign's plant alone, and the throughput ceiling it leaves with the solves (a profile of the project itself).

Run from the repository root::

    python scripts/plant_bench.py                                   # configs/random.toml's plant, 2000 periods
    python scripts/plant_bench.py --sweep results/ref40 --json results/plant.json   # and that sweep's ceiling

:func:`run_plant_bench` times one control period of the simulated plant of a randomized sweep
(``SimRobotIO.wait`` after ``send_velocity``: the scripted person's mocap update, the decoupled
velocity drive's torque and MuJoCo's sub-steps) on a realized scenario of the config's family,
driven by a fixed random command sequence within ±0.3 rad/s. Nothing of a method, of sensing or
of recording runs in it.

:func:`throughput_ceiling` reads a finished sweep's per-step solve times and answers: how many
simulated seconds per CPU second could the sweep reach if each control step cost only its
method's solve and the plant,

.. math:: \text{ceiling} = \frac{\Delta t}{\overline{t}_{solve} + \overline{t}_{plant}}

with :math:`\overline{t}_{solve}` the mean solve time over every step of every method (each method
runs the same number of steps) and :math:`\Delta t` the control period. A sweep's measured rate
is below it by what the rest of the loop costs (sensing, ground truth, recording, the status
check, start-up, results) and by two workers sharing a machine.
"""

from __future__ import annotations

import json
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from compare.analysis.results import CONFIG_FILE, RUNS_DIR, load_steps, load_summary
from compare.arguments import ArgumentParser, existing_dir, existing_file, output_path, positive_int
from compare.bench.timing import BenchRow, summarize
from compare.config import Config, load_config
from compare.exceptions import CompareError
from compare.loop.simulation import build_simulation
from compare.scenarios.random_scenario import realize
from compare.versions import versions

RANDOM_CONFIG = Path(__file__).resolve().parents[1] / "configs" / "random.toml"
"""The scenario family whose plant is timed by default (the reference campaign's)."""

MIN_STEPS = 200
"""Fewest timed control periods the command line accepts (enough for a p95)."""

COMMAND_RAD_S = 0.3
"""Largest joint velocity of the random command sequence [rad/s]."""


def run_plant_bench(config: Config, steps: int = 2000, seed: int = 0) -> BenchRow:
    """Time ``steps`` control periods of ``config``'s plant (module docstring).

    Args:
        config: A scenario (``kind = "random"`` families are realized first); its
            ``scenario.simulation`` / ``drive`` choose the plant.
        steps: Timed control periods, after 50 untimed ones on a separate copy of the plant.
        seed: Seed of the command sequence.

    Returns:
        Row ``plant`` / ``<simulation>-<drive>``: median and p95 per period [µs] (wall clock);
        ``extra`` holds the mean [µs], the mean on the thread's CPU clock ``cpu_mean_us`` [µs],
        the control period [s] and the physics sub-steps per period.
    """
    robot = config.load_robot()
    realized = realize(config, robot) if config.scenario.kind == "random" else config
    sc = realized.scenario
    q0 = np.array(sc.start_q) if sc.start_q is not None else robot.home.copy()
    commands = np.random.default_rng(seed).uniform(-COMMAND_RAD_S, COMMAND_RAD_S, (steps, robot.nq))
    warm = build_simulation(realized, robot, q0).io
    for k in range(min(50, steps)):
        warm.send_velocity(commands[k])
        warm.wait()
    io = build_simulation(realized, robot, q0).io
    out = np.empty(steps)
    clock = time.perf_counter_ns
    cpu0 = time.thread_time_ns()
    for k in range(steps):
        t0 = clock()
        io.send_velocity(commands[k])
        io.wait()
        out[k] = (clock() - t0) * 1e-3
    cpu_us = (time.thread_time_ns() - cpu0) * 1e-3 / steps
    case = f"{sc.simulation}-{sc.drive}"
    return summarize(
        "plant", case, out, mean_us=float(out.mean()), cpu_mean_us=cpu_us, dt_s=sc.dt, substeps=float(io.substeps)
    )


@dataclass(frozen=True)
class SweepSolves:
    """A finished sweep's mean solve time per step of each method, and its control period.

    Attributes:
        mean_solve_us: Mean ``solve_time_us`` over every step of every run, by method [µs].
        dt_s: Control period [s] (median step interval of the tables).
    """

    mean_solve_us: dict[str, float]
    dt_s: float


def read_sweep_solves(sweep_dir: Path) -> SweepSolves:
    """The per-step solve times of a finished sweep: every method of every run's ``summary.json``.

    Raises:
        FileNotFoundError: ``sweep_dir`` holds no finished run, or a run's method has no step table.
    """
    runs_dir = Path(sweep_dir) / RUNS_DIR
    per_method: dict[str, list[np.ndarray]] = {}
    dts: list[float] = []
    for run_dir in sorted(p for p in runs_dir.iterdir() if p.is_dir()) if runs_dir.is_dir() else []:
        try:
            summary = load_summary(run_dir)
        except (OSError, ValueError):  # not finished (or being written)
            continue
        for method in summary.get("methods") or {}:
            steps = load_steps(run_dir, method, columns=["t", "solve_time_us"])
            per_method.setdefault(method, []).append(steps["solve_time_us"].to_numpy(dtype=float))
            if len(steps) > 1:
                dts.append(float(np.median(np.diff(steps["t"].to_numpy(dtype=float)))))
    if not per_method:
        raise FileNotFoundError(
            f"{sweep_dir}: no finished run with step tables under {RUNS_DIR}/ (not a finished sweep)"
        )
    means = {m: float(np.concatenate(v).mean()) for m, v in per_method.items()}
    return SweepSolves(means, float(np.median(dts)))


def throughput_ceiling(solves: SweepSolves, plant_us: float) -> dict[str, float | dict[str, float]]:
    """The simulated seconds per CPU second a sweep could reach with only solves and plant (module docstring).

    Args:
        solves: The sweep's solve times (:func:`read_sweep_solves`).
        plant_us: Mean cost of the plant per control period [µs] (:func:`run_plant_bench`).

    Returns:
        ``mean_solve_us`` per method, their mean ``mean_solve_all_us``, ``plant_us``, ``dt_s`` and
        ``ceiling_sim_s_per_cpu_s``.
    """
    solve_all = float(np.mean(list(solves.mean_solve_us.values())))
    return {
        "mean_solve_us": dict(solves.mean_solve_us),
        "mean_solve_all_us": solve_all,
        "plant_us": plant_us,
        "dt_s": solves.dt_s,
        "ceiling_sim_s_per_cpu_s": solves.dt_s / ((solve_all + plant_us) * 1e-6),
    }


def plant_config_of(explicit: Path | None, sweep_dir: Path | None) -> Path:
    """The config whose plant is timed: the one given, else the sweep's own copy, else the random family."""
    if explicit is not None:
        return explicit
    if sweep_dir is not None and (sweep_dir / CONFIG_FILE).is_file():
        return sweep_dir / CONFIG_FILE
    return RANDOM_CONFIG


def main(argv: Sequence[str] | None = None) -> int:
    """Time the plant, and with ``--sweep`` the sweep's ceiling; print them, write ``--json``; the exit code."""
    parser = ArgumentParser(
        prog="python scripts/plant_bench.py",
        description=__doc__.splitlines()[0] + "\n\nPrints the median, p95 and mean time of one control period "
        "[µs]; with --sweep, the simulated\nseconds per CPU second the sweep's solves and this plant allow.",
    )
    parser.add_argument(
        "--family",
        type=existing_file,
        metavar="TOML",
        help="scenario family (default: the --sweep's config.toml, else configs/random.toml)",
    )
    parser.add_argument(
        "--sweep", type=existing_dir, metavar="DIR", help="a finished sweep, for its throughput ceiling"
    )
    parser.add_argument(
        "--steps", type=positive_int, default=2000, metavar="N", help=f"timed control periods, at least {MIN_STEPS}"
    )
    parser.add_argument(
        "--json", type=output_path, dest="json_out", metavar="FILE", help="write the row and the ceiling as JSON"
    )
    args = parser.parse_args(argv)
    if args.steps < MIN_STEPS:
        parser.error(f"argument --steps: expected at least {MIN_STEPS}, got {args.steps}")
    try:  # the sweep first: a wrong directory is refused before the plant is timed
        sweep = read_sweep_solves(args.sweep) if args.sweep is not None else None
        family = plant_config_of(args.family, args.sweep)
        config, _ = load_config(family, {"scenario.sensing": "geometric"})
    except (FileNotFoundError, CompareError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    row = run_plant_bench(config, steps=args.steps)
    print(
        f"plant alone, one control period ({family}, {row.case}): median {row.median_us:.1f} µs, "
        f"p95 {row.p95_us:.1f} µs, mean {row.extra['mean_us']:.1f} µs (wall clock); "
        f"mean {row.extra['cpu_mean_us']:.1f} µs (CPU clock)"
    )
    payload: dict[str, object] = {
        "versions": versions(),
        "command": " ".join(["python", "scripts/plant_bench.py", *(argv if argv is not None else sys.argv[1:])]),
        "results": [row.to_dict()],
    }
    if sweep is not None:
        ceiling = {**throughput_ceiling(sweep, row.extra["mean_us"]), "plant_config": str(family)}
        solves = ", ".join(f"{m} {us:.1f}" for m, us in sweep.mean_solve_us.items())
        print(
            f"throughput ceiling of {args.sweep}: mean solve per step [µs] {solves} "
            f"(all {ceiling['mean_solve_all_us']:.1f}) + plant {row.extra['mean_us']:.1f} → "
            f"{ceiling['ceiling_sim_s_per_cpu_s']:.1f} simulated s per CPU s"
        )
        payload["throughput_ceiling"] = ceiling
    if args.json_out is not None:
        args.json_out.parent.mkdir(parents=True, exist_ok=True)
        args.json_out.write_text(json.dumps(payload, indent=2) + "\n", encoding="utf-8")
        print(f"wrote {args.json_out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

r"""The campaign's plant alone, and the throughput ceiling it leaves with the methods' solves.

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

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from compare.analysis.results import RUNS_DIR, load_steps, load_summary
from compare.bench.timing import BenchRow, summarize
from compare.config import Config

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
        Row ``plant`` / ``<simulation>-<drive>``: median and p95 per period [µs]; ``extra`` holds
        the mean [µs], the control period [s] and the physics sub-steps per period.
    """
    from compare.loop.simulation import build_simulation
    from compare.scenarios.random_scenario import realize

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
    for k in range(steps):
        t0 = clock()
        io.send_velocity(commands[k])
        io.wait()
        out[k] = (clock() - t0) * 1e-3
    case = f"{sc.simulation}-{sc.drive}"
    return summarize("plant", case, out, mean_us=float(out.mean()), dt_s=sc.dt, substeps=float(io.substeps))


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

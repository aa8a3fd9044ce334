"""Solver micro-benchmarks: one full control step per call, kinematics included.

Two tables:

* **case 2** (:func:`run_solver_bench`): every method of :mod:`compare.methods` on the paper's
  case-2 hierarchy at the states of :func:`compare.bench.solver_cases.case2_states` (cases
  ``case2-active0/1/3``);
* **TPIK vs |C|** (:func:`run_candidate_bench`): the same four levels (3 joint limits > 6
  walls > 3 obstacle distances > EE position) with thresholds, walls and obstacle points placed
  around one configuration so that exactly ``k`` set-based tasks are candidates (cases
  ``tpik-candidates-<k>``): the cost of the 2^|C| mode search, and of greedy release above
  ``max_exhaustive_candidates``.

A timed call is ``kin = robot.kinematics(q); solver.solve(hierarchy, kin, dt)``. The reference
of every ratio (``ratio_to_mink``, "× mink") is ``mink-native``
(:class:`compare.bench.mink_native.MinkCase2`): the same problem written with mink's API alone,
one call = ``configuration.update(q)`` + its rows + what ``mink.solve_ik`` does. The
``mink`` row is the project's adapter (our task layer on mink's kinematics), timed beside it.
Methods are timed in interleaved blocks of 10 calls, so a slow phase of a shared machine hits
every method alike and the ratios to the reference stay meaningful.

"× mink" compares whole steps, and a mink step is mostly Python (its problem build and the row
updates) around a small QP solve: the ratio is largely compiled code against mink's Python layer,
not one algorithm against another. Every timed call is therefore also split, in the same calls,
into its **core** — the QP solver (mink-native, the mink peers, HQP: every backend call and
linear solve) or TPIK's compiled step (its kinematics, rows and mode search) — its **build**
(``mink.build_ik``; HQP's assembly of its levels; TPIK's Python part before the compiled step),
its **rows** (the mink peers and mink-native: kinematics and row updates) and the **rest** (the
call minus those three: the kinematics snapshot, checks, the result) (:func:`call_split`);
``core_ratio_to_mink`` compares the cores alone.
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

import robots
from compare.bench.mink_native import MinkCase2
from compare.bench.solver_cases import apply_state, case2_hierarchy, case2_states
from compare.bench.timing import BenchRow, summarize, time_calls
from compare.methods import make_method
from robots import Robot
from tpik.exceptions import TargetNotSet
from tpik.hierarchy import Hierarchy, Level
from tpik.solver import TpikSettings, TpikSolver
from tpik.step_result import IkSolver, StepResult
from tpik.tasks import JointLimitTask, ObstacleDistanceTask, PositionTask, Task, Thresholds, VirtualWallTask

DT = 0.01
"""Control period of the benchmark steps [s] (100 Hz, as the loop)."""

DEFAULT_METHODS = ["tpik", "tpik-paper", "tpik-ss", "hqp-daqp", "mink", "mink-posture"]
REFERENCE = "mink-native"
"""The reference of every ratio: mink alone on the same problem (:mod:`compare.bench.mink_native`)."""
BLOCK = 10


def build_methods(
    names: Sequence[str], robot: Robot, settings: Mapping[str, Mapping[str, Any]] | None = None
) -> dict[str, IkSolver]:
    """Build the named methods; a method that cannot be built is skipped with a printed note."""
    built: dict[str, IkSolver] = {}
    for name in names:
        try:
            built[name] = make_method(name, robot, (settings or {}).get(name))
        except Exception as exc:  # ImportError, UnknownMethod, a backend's own error
            print(f"note: skipping method '{name}': {type(exc).__name__}: {exc}")
    return built


def interleaved(
    fns: Mapping[str, Callable[[], object]],
    repeats: int,
    block: int = BLOCK,
    outputs: Mapping[str, list[object]] | None = None,
) -> dict[str, np.ndarray]:
    """Time several functions in alternating blocks of ``block`` calls; durations per call [µs].

    With ``outputs``, ``outputs[name]`` receives the return value of each of ``name``'s timed
    calls, in the order of its durations.
    """
    for fn in fns.values():
        time_calls(fn, 1, warmup=20)
    out: dict[str, list[np.ndarray]] = {name: [] for name in fns}
    for _ in range(max(1, math.ceil(repeats / block))):
        for name, fn in fns.items():
            out[name].append(time_calls(fn, block, warmup=0, outputs=None if outputs is None else outputs[name]))
    if outputs is not None:
        for values in outputs.values():
            del values[repeats:]
    return {name: np.concatenate(chunks)[:repeats] for name, chunks in out.items()}


def _step(robot: Robot, solver: IkSolver, hierarchy: Hierarchy, q: np.ndarray) -> Callable[[], object]:
    def call() -> object:
        return solver.solve(hierarchy, robot.kinematics(q), DT)

    return call


def _native_step(native: MinkCase2, q: np.ndarray) -> Callable[[], object]:
    def call() -> object:
        native.step(q, DT)
        return native.parts_s

    return call


SPLIT = ("core_us", "build_us", "rows_us", "rest_us")
"""The parts of a timed call (:func:`call_split`), each a median over the timed calls in a row's ``extra``."""


def call_split(total_us: float, output: object) -> dict[str, float]:
    """One timed call of ``total_us`` split into core, build, rows and the rest [µs] (module docstring).

    ``output`` is what the call returned: mink-native's ``parts_s`` (rows, build, solver) [s], or a
    method's :class:`~tpik.step_result.StepResult`: core = ``solve_time_s``; build = the mink
    peers' ``extras["problem_build_s"]`` (``mink.build_ik``), else ``build_time_s`` (HQP's
    assembly, TPIK's Python part); rows = the rest of a mink peer's ``build_time_s``. The rest is
    ``total_us`` minus the three (≥ 0 when the parts lie inside the call, as they do).
    """
    if isinstance(output, tuple):
        rows_s, build_s, core_s = output
    else:
        assert isinstance(output, StepResult)
        core_s = output.solve_time_s
        problem = output.extras.get("problem_build_s")
        if isinstance(problem, float):  # a mink peer: its build_time_s is the row updates and build_ik
            build_s, rows_s = problem, output.build_time_s - problem
        else:
            build_s, rows_s = output.build_time_s, 0.0
    core, build, rows = 1e6 * core_s, 1e6 * build_s, 1e6 * rows_s
    return {"core_us": core, "build_us": build, "rows_us": rows, "rest_us": total_us - core - build - rows}


def _extras(samples_us: np.ndarray, outputs: Sequence[object]) -> dict[str, float]:
    """Median of each part of :func:`call_split` over the timed calls, and what the method reported."""
    splits = [call_split(float(t), out) for t, out in zip(samples_us, outputs, strict=True)]
    extra = {key: float(np.median([sp[key] for sp in splits])) for key in SPLIT}
    extra["core_fraction"] = float(np.median([sp["core_us"] / t for sp, t in zip(splits, samples_us, strict=True)]))
    results = [out for out in outputs if isinstance(out, StepResult)]
    if not results:
        return extra
    extra["ok_fraction"] = sum(bool(r.ok) for r in results) / len(results)
    extra["active"] = float(len(results[-1].active_set))
    for key in ("candidates", "modes_evaluated"):
        value = results[-1].extras.get(key)
        if isinstance(value, int | float):
            extra[key] = float(value)
    return extra


def native_for(robot: Robot, hierarchy: Hierarchy) -> MinkCase2:
    """``mink-native`` for a case-2-shaped hierarchy: its thresholds, gains, obstacle points and target.

    Only the numbers are read from the hierarchy (once, untimed); a step is mink alone.
    """
    joints, walls, gains, obstacles = [], [], {}, {}
    safety_distance, target = 0.35, None
    for task in hierarchy.tasks:
        if isinstance(task, JointLimitTask):
            th = task.thresholds
            joints.append((robot.joint_names[task.joint - 1], th.safety_lower, th.safety_upper))
            gains["joint_limits"] = task.gain
        elif isinstance(task, VirtualWallTask):
            walls.append((task.normal, task.offset))
            gains["walls"] = task.gain
        elif isinstance(task, ObstacleDistanceTask):
            safety_distance = task.thresholds.safety_lower
            obstacles[task.frame] = task.obstacle
            gains["obstacles"] = task.gain
        elif isinstance(task, PositionTask):
            with contextlib.suppress(TargetNotSet):  # no target yet: set_scene gives it
                target = task.target
            gains["position"] = task.gain
    velocities = {name: float(v) for name, v in zip(robot.joint_names, robot.v_max, strict=True)}
    bodies = [robot.mujoco_body(frame) for frame in obstacles]
    native = MinkCase2(
        robot.mj_model, velocities, joints, walls, robot.mujoco_body(robot.ee_frame), bodies, safety_distance, gains
    )
    native.set_scene(list(obstacles.values()), target if target is not None else np.zeros(3))
    return native


def _rows_for(
    robot: Robot,
    solvers: Mapping[str, IkSolver],
    hierarchies: Mapping[str, Hierarchy],
    q: np.ndarray,
    case: str,
    repeats: int,
    native: MinkCase2 | None = None,
) -> list[BenchRow]:
    fns: dict[str, Callable[[], object]] = {}
    if native is not None:
        fns[REFERENCE] = _native_step(native, q)
    for name, solver in solvers.items():
        try:
            solver.solve(hierarchies[name], robot.kinematics(q), DT)
        except Exception as exc:
            print(f"note: skipping method '{name}' on {case}: {type(exc).__name__}: {exc}")
            continue
        fns[name] = _step(robot, solver, hierarchies[name], q)
    outputs: dict[str, list[object]] = {name: [] for name in fns}
    samples = interleaved(fns, repeats, outputs=outputs)
    rows = [summarize(name, case, us, **_extras(us, outputs[name])) for name, us in samples.items()]
    return _with_ratios(rows)


def _with_ratios(rows: list[BenchRow]) -> list[BenchRow]:
    """Add ``ratio_to_mink`` (median / median of ``mink-native`` in the same case) and ``core_ratio_to_mink``."""
    ref = {r.case: r for r in rows if r.name == REFERENCE}
    out = []
    for r in rows:
        extra = dict(r.extra)
        native = ref.get(r.case)
        if native is not None:
            extra["ratio_to_mink"] = r.median_us / native.median_us
            if "core_us" in extra and native.extra.get("core_us", 0.0) > 0.0:
                extra["core_ratio_to_mink"] = extra["core_us"] / native.extra["core_us"]
        out.append(BenchRow(r.name, r.case, r.median_us, r.p95_us, r.samples, extra))
    return out


def run_solver_bench(
    method_names: list[str],
    repeats: int,
    robot: Robot | None = None,
    description: Sequence[Mapping[str, Any]] | None = None,
    settings: Mapping[str, Mapping[str, Any]] | None = None,
) -> list[BenchRow]:
    """Time one control step of each method on the case-2 states (``case2-active0/1/3``).

    Args:
        method_names: Names for :func:`compare.methods.make_method` (``tpik``, ``mink``, ...);
            a method whose import or construction fails is skipped with a printed note.
        repeats: Timed calls per method and case.
        robot: The arm (default :data:`robots.DEFAULT_ROBOT`).
        description: The case-2 levels (a config's); default the robot's
            :func:`~compare.bench.solver_cases.case2_description`.
        settings: Per-method settings (a config's ``[methods.settings]``).

    Returns:
        One row per (method, case), ``mink-native`` first: median and p95 [µs], ``extra`` with
        the split of the same timed calls (:data:`SPLIT`: ``core_us``, ``build_us``, ``rows_us``,
        ``rest_us``; ``core_fraction``), the active set size, ``ratio_to_mink`` and
        ``core_ratio_to_mink`` (to ``mink-native``, timed in the same interleaved run).
    """
    robot = robot or robots.load(robots.DEFAULT_ROBOT)
    solvers = build_methods(method_names, robot, settings)
    hierarchies = {name: case2_hierarchy(robot, description) for name in solvers}  # one per method: solvers may cache
    rows: list[BenchRow] = []
    for state in case2_states(robot, description=description):
        for h in hierarchies.values():
            apply_state(h, state)
        reference = case2_hierarchy(robot, description)
        apply_state(reference, state)
        native = native_for(robot, reference)
        rows += _rows_for(robot, solvers, hierarchies, state.q, state.name, repeats, native)
    return rows


def candidate_hierarchy(robot: Robot, q: np.ndarray, k: int) -> Hierarchy:
    """Case-2 levels around ``q`` with exactly ``k`` candidate set-based tasks (0 ≤ k ≤ 12).

    Activated in this order: obstacle points 0.37 m from the control points (safety 0.35,
    ε = 0.05), walls 0.02 m from the EE (ε = 0.03; opposite walls make a narrow box), then
    joint limits whose upper safety threshold is 0.02 rad above q (ε = 0.05). The others are
    far from their thresholds, so every k evaluates the same 13 tasks.
    """
    if not 0 <= k <= 12:
        raise ValueError(f"k must be in 0..12, got {k}")
    kin = robot.kinematics(q)
    ee = kin.frame_position(robot.ee_frame)
    obstacles: list[Task] = []
    for i, frame in enumerate(robot.control_points[:3]):
        task = ObstacleDistanceTask(f"obstacle_{frame}", frame, Thresholds(0.1, 0.35, math.inf, math.inf, 0.05))
        offset = 0.37 if i < k else 1.5
        task.set_obstacle(kin.frame_position(frame) + offset * np.array([0.0, 0.6, 0.8]))
        obstacles.append(task)
    walls: list[Task] = []
    wall_th = Thresholds(-0.05, 0.0, math.inf, math.inf, 0.03)
    for i, (axis, sign) in enumerate((a, s) for a in range(3) for s in (1.0, -1.0)):
        normal = np.zeros(3)
        normal[axis] = sign
        gap = 0.02 if 3 + i < k else 0.5
        walls.append(
            VirtualWallTask(
                f"wall_{'xyz'[axis]}_{'min' if sign > 0 else 'max'}",
                robot.ee_frame,
                normal,
                sign * ee[axis] - gap,
                wall_th,
            )
        )
    limits: list[Task] = []
    for i, joint in enumerate((2, 4, 6)):
        qj = float(q[joint - 1])
        above = 0.02 if 9 + i < k else 1.0
        th = Thresholds(qj - 2.0, qj - 1.0, qj + above, qj + above + 0.1, 0.05)
        limits.append(JointLimitTask(f"joint_limit_{joint}", joint, robot.nq, th))
    target = PositionTask(f"position_{robot.ee_frame}", robot.ee_frame, target=ee + np.array([0.05, -0.05, 0.05]))
    return Hierarchy(
        [
            Level("joint_limits", tuple(limits)),
            Level("walls", tuple(walls)),
            Level("obstacles", tuple(obstacles)),
            Level("operational", (target,)),
        ]
    )


def run_candidate_bench(
    repeats: int,
    max_candidates: int = 8,
    method_names: Sequence[str] = ("tpik", "tpik-ss"),
    robot: Robot | None = None,
) -> list[BenchRow]:
    """TPIK step time against the number of candidate set tasks |C| (cases ``tpik-candidates-<k>``).

    Besides the named methods, ``tpik-exhaustive`` is TPIK with ``max_exhaustive_candidates``
    = 12, so the 2^|C| growth shows past the default greedy threshold.

    Args:
        repeats: Timed calls per method and case.
        max_candidates: Largest |C| (≤ 12).
        method_names: Methods timed at every |C| (``mink-native`` on the same hierarchy is the
            reference).
        robot: The arm (default :data:`robots.DEFAULT_ROBOT`).
    """
    robot = robot or robots.load(robots.DEFAULT_ROBOT)
    q = case2_states(robot)[0].q
    solvers = _candidate_methods(robot, method_names)
    rows: list[BenchRow] = []
    for k in range(max_candidates + 1):
        hierarchies = {name: candidate_hierarchy(robot, q, k) for name in solvers}
        native = native_for(robot, candidate_hierarchy(robot, q, k))
        rows += _rows_for(robot, solvers, hierarchies, q, f"tpik-candidates-{k}", repeats, native)
    return rows


def _candidate_methods(robot: Robot, method_names: Sequence[str]) -> dict[str, IkSolver]:
    solvers = build_methods(list(method_names), robot)
    solvers["tpik-exhaustive"] = TpikSolver(robot, TpikSettings(max_exhaustive_candidates=12), name="tpik-exhaustive")
    return solvers

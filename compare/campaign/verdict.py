"""The verdict of a run: could any motion of the arm have kept the person beyond the safety threshold?

Each run of a scenario with a scripted person gets one label (docs/design.md §5, §7):

* ``avoidable``: a *witness* (:mod:`compare.campaign.witness`) — a policy that knows the person's
  future and drives the same plant under the same limits — kept every obstacle, joint-limit and
  wall safety threshold over the whole run, judged by the methods' own metrics. This shows that
  holding the thresholds was possible (with foreknowledge of the person).
* ``unavoidable``: no witness held, and the reachability certificate
  (:mod:`compare.campaign.reachability`) shows that every motion within the joint velocity
  limits brings some control point within the safety threshold: impossible to hold.
* ``undecided``: neither. A witness that fails proves nothing, so this is not "unavoidable".

The witnesses are tried in the order of ``[oracle] witnesses`` (the oracle at several horizons,
the greedy preview policy at several previews); with ``witness_rule = "first"`` the search
stops at the first that holds, with ``"all"`` every witness runs. The entry records each
witness run, the best minimum distance among them, and which held; a method's obstacle
violations in the run are counted under the run's label.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import Any

import numpy as np

import robots
from compare.analysis.metrics import VIOLATION_TOLERANCE, to_jsonable
from compare.campaign.reachability import prove_unavoidable, reach_bound
from compare.campaign.witness import WitnessSpec, cached_witness
from compare.config import Config
from compare.sensing.person import Person
from compare.sensing.person_track import PersonTrack
from tpik.tasks import ObstacleDistanceTask

log = logging.getLogger(__name__)

LABELS = ("avoidable", "unavoidable", "undecided")
"""The three labels of a run."""


def certify(config: Config, robot: robots.Robot) -> dict[str, Any] | None:
    """The reachability certificate of a realized scenario: the first control point proven, or None."""
    sc = config.scenario
    hierarchy = config.build_hierarchy(robot)
    tasks = [t for t in hierarchy.set_tasks if isinstance(t, ObstacleDistanceTask)]
    q0 = np.array(sc.start_q) if sc.start_q is not None else robot.home.copy()
    kin = robot.kinematics(q0)
    starts = {t.frame: kin.frame_position(t.frame).copy() for t in tasks}
    person = Person(robot.workcell_model(), config.person.keyframes, time_scale=sc.time_scale)
    track = PersonTrack.from_person(person, sc.sim_time_s + 1.0, sc.dt)
    proofs = []
    for task in tasks:
        proof = prove_unavoidable(
            reach_bound(robot, task.frame),
            starts[task.frame],
            track,
            task.thresholds.safety_lower,
            sc.sim_time_s,
            sc.dt,
            voxel_m=config.oracle.certificate_voxel_m,
            tolerance_m=VIOLATION_TOLERANCE,
        )
        if proof is not None:
            proofs.append(proof)
    if not proofs:
        return None
    first = min(proofs, key=lambda p: p.time_s)
    return {
        "control_point": first.frame,
        "time_s": first.time_s,
        "speed_bound_mps": first.reach_mps,
        "voxel_m": first.voxel_m,
    }


def run_verdict(
    config: Config,
    robot: robots.Robot,
    cache_dir: Path | None = None,
    stop_at_violation: bool = False,
    certificate: bool = True,
) -> dict[str, Any]:
    """The label of a realized scenario and the evidence (module docstring).

    Args:
        config: A realized scenario (random after :func:`compare.scenarios.random_scenario.realize`,
            or scripted).
        robot: The arm.
        cache_dir: Where witness runs are cached (None: not cached).
        stop_at_violation: Each witness stops at its first threshold passed (it then only says
            "did not hold"; its minimum distance is that of the part it ran). Used to reject draws.
        certificate: Search the reachability certificate when no witness holds (else the run is
            ``undecided`` then).

    Returns:
        ``summary.json["oracle"]``: ``label``, ``witness`` (the held witness with the largest
        minimum distance, or None), ``min_distance_m`` (the largest over the witnesses run),
        ``held_safety`` (``label == "avoidable"``), ``witnesses`` (each run's entry),
        ``certificate`` (or None), ``safety_threshold_m``, ``wall_time_s``.
    """
    start = time.perf_counter()
    settings = config.oracle
    runs: dict[str, dict[str, Any]] = {}
    for name in settings.witnesses:
        entry = cached_witness(config, robot, WitnessSpec.parse(name), cache_dir, stop_at_violation).entry
        runs[name] = {k: v for k, v in entry.items() if k not in ("witness", "key")}
        log.debug("witness %s: held=%s min distance %s", name, entry["held"], entry["min_distance_m"])
        if entry["held"] and settings.witness_rule == "first":
            break
    held = {n: e for n, e in runs.items() if e["held"]}
    dists = {n: e["min_distance_m"] for n, e in runs.items() if e.get("min_distance_m") is not None}
    proof = None if held or not certificate else certify(config, robot)
    label = "avoidable" if held else "unavoidable" if proof is not None else "undecided"
    tasks = [t for t in config.build_hierarchy(robot).set_tasks if isinstance(t, ObstacleDistanceTask)]
    entry = {
        "label": label,
        "witness": max(held, key=lambda n: dists.get(n, -np.inf)) if held else None,
        "min_distance_m": max(dists.values()) if dists else None,
        "held_safety": bool(held),
        "witnesses": runs,
        "certificate": proof,
        "witness_rule": settings.witness_rule,
        "safety_threshold_m": min((t.thresholds.safety_lower for t in tasks), default=None),
        "wall_time_s": time.perf_counter() - start,
    }
    return to_jsonable(entry)

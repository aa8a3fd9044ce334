r"""The paper's claims of Sec. IV, checked one by one on a run's per-step table (docs/design.md §5).

Each claim is a function of the per-step table (columns in :mod:`compare.analysis.metrics`), the
set tasks' thresholds and the person's timeline from the scenario's keyframes. A set task
*activates* when its value σ (as the controller saw it, column ``sigma:N``) enters the
activation band of eq. 7 (:math:`\sigma \le \sigma_{a,l}` or :math:`\ge \sigma_{a,u}`): the
same test for every method, whatever the solver reports as its own active set. Distances are the
ground truth (``truth:N``), as in the safety metrics; "stays above" allows the metrics' violation
tolerance (1 mm / 1 mrad).

Case 1 (Sec. IV-B, Figs. 3–5):

* ``c1_free_before``: before the person steps in (until their first motion), the arm reaches both
  waypoints while the person stays outside the obstacle tasks' activation thresholds (true
  distances) and no obstacle task activates;
* ``c1_obstacle_tasks``: the wrist and hand obstacle tasks (second and third control points)
  activate while the person is in, and only those two;
* ``c1_arm_stops``: the arm stops while they are active: from 1 s after the person has arrived and
  a task has activated to the person leaving, the EE makes no progress (median over 1 s windows of
  its net displacement below 2 cm/s; chatter in place is path, not progress) and reaches no
  waypoint (the position error stays high, Fig. 3);
* ``c1_distances``: every control point stays beyond the obstacle safety threshold (0.35 m);
* ``c1_joint4_limit``: the joint-4 limit task activates and joint 4 stays within its safety
  thresholds;
* ``c1_resumes``: after the person leaves, the obstacle tasks deactivate (within 2 s of the
  person's last keyframe) and the EE reaches a waypoint again.

Case 2 (Sec. IV-C, Figs. 6–10):

* ``c2_moves_away``: while the person reaches in, an obstacle task activates and the arm moves
  away: the EE leaves its start position by at least :data:`MOVED_AWAY_M` (Fig. 6);
* ``c2_inside_box``: while the person pushes, a wall task activates and the EE stays within
  every wall's safety threshold;
* ``c2_distances``: every control point stays beyond the obstacle safety threshold;
* ``c2_joint_limits``: the joints stay within their limits' safety thresholds;
* ``c2_returns``: after the person steps away the EE returns to its start position (within the
  waypoint tolerance) before the end of the run (Fig. 7);
* ``c2_chattering``: the chattering of Fig. 9 is the person's doing ("the person is moving and the
  points at minimum distance change"): the obstacle tasks' activations toggle only while the
  person moves, none while the person stands still (before the first motion, and from
  :data:`DEACTIVATION_GRACE_S` after the last keyframe).

Every threshold above is a module constant or a config value, fixed before any result was looked
at; a claim holds for a method in a set of runs only when it holds in each run.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from compare.analysis.critical_speed_results import CLAIMS_FILE, DETAIL_FILE
from compare.analysis.metrics import VIOLATION_TOLERANCE, margins, set_task_infos, to_jsonable
from compare.analysis.person_speeds import keyframe_speeds
from compare.analysis.results import load_steps, load_summary
from compare.config import Config, load_config

SETTLE_S = 1.0
"""Time after the first obstacle activation before "the arm stops" is measured [s]."""
STOPPED_SPEED_MPS = 0.02
"""EE progress (median over 1 s windows of the net displacement) below which the arm has stopped [m/s]."""
STOP_WINDOW_S = 1.0
"""Window of the net EE displacement [s]: a controller chattering in place makes path, no progress."""
DEACTIVATION_GRACE_S = 2.0
"""Time after the person's last keyframe within which the obstacle tasks must be inactive [s]."""
MOVED_AWAY_M = 0.05
"""EE displacement from its start that counts as "the arm moves away" in case 2 [m]."""


@dataclass(frozen=True)
class TaskBand:
    """Thresholds of one scalar set task, activation included.

    Attributes:
        name: Task name (``sigma:<name>`` column).
        group: ``joint_limits``, ``walls``, ``obstacles`` or ``other``.
        safety_lower: σ_{s,l}.
        safety_upper: σ_{s,u}.
        activation_lower: σ_{a,l} = σ_{s,l} + ε.
        activation_upper: σ_{a,u} = σ_{s,u} − ε.
    """

    name: str
    group: str
    safety_lower: float
    safety_upper: float
    activation_lower: float
    activation_upper: float


@dataclass(frozen=True)
class PersonTimeline:
    """When the person moves, from the keyframes (scaled times) [s].

    Attributes:
        t_move: Start of the first motion (stepping in).
        t_in: End of the first motion block (the person has arrived).
        t_leave: Start of the last motion block (stepping away).
        t_gone: The person's last keyframe.
    """

    t_move: float
    t_in: float
    t_leave: float
    t_gone: float


@dataclass(frozen=True)
class ClaimContext:
    """What the claim checks need besides the steps.

    Attributes:
        kind: ``case1`` or ``case2``.
        tasks: Every set task with its thresholds.
        control_points: Frames of the obstacle control points, in hierarchy order.
        person: The person's timeline.
        waypoint_tolerance_m: EE error below which a waypoint counts as reached [m].
    """

    kind: str
    tasks: tuple[TaskBand, ...]
    control_points: tuple[str, ...]
    person: PersonTimeline
    waypoint_tolerance_m: float

    def group(self, name: str) -> list[TaskBand]:
        """The tasks of one group."""
        return [t for t in self.tasks if t.group == name]

    @property
    def run_time_needed_s(self) -> float:
        """The run time the claims read: to :data:`DEACTIVATION_GRACE_S` after the person's last keyframe [s]."""
        return self.person.t_gone + DEACTIVATION_GRACE_S


@dataclass(frozen=True)
class Claim:
    """One claim measured on one run.

    Attributes:
        key: Identifier (``c1_distances``, ...).
        claim: The claim as the paper states it.
        holds: Whether the run meets it.
        measured: What was measured, in words and numbers.
        values: The numbers (JSON-ready).
    """

    key: str
    claim: str
    holds: bool
    measured: str
    values: dict[str, Any]

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict."""
        return to_jsonable(
            {"key": self.key, "claim": self.claim, "holds": self.holds, "measured": self.measured, **self.values}
        )


# --------------------------------------------------------------------------------- context


def person_timeline(keyframes: Sequence[Any], time_scale: float = 1.0) -> PersonTimeline | None:
    """Motion blocks of the keyframes: a segment moves when any field of its two ends differs.

    Returns:
        The timeline, or None when the person never moves.
    """
    frames = list(keyframes)
    moving = []
    for a, b in zip(frames, frames[1:], strict=False):
        same = (
            tuple(a.position) == tuple(b.position)
            and a.yaw == b.yaw
            and a.right_hand == b.right_hand
            and a.left_hand == b.left_hand
        )
        moving.append(not same)
    if not any(moving):
        return None
    blocks: list[tuple[float, float]] = []
    for k, flag in enumerate(moving):
        if not flag:
            continue
        t0, t1 = frames[k].t * time_scale, frames[k + 1].t * time_scale
        if blocks and math.isclose(blocks[-1][1], t0):
            blocks[-1] = (blocks[-1][0], t1)
        else:
            blocks.append((t0, t1))
    return PersonTimeline(blocks[0][0], blocks[0][1], blocks[-1][0], blocks[-1][1])


def context_from_config(config: Any) -> ClaimContext | None:
    """The claim context of a scripted case config (:class:`compare.config.Config`); None otherwise."""
    kind = config.scenario.kind
    if kind not in ("case1", "case2"):
        return None
    timeline = person_timeline(config.person.keyframes, config.scenario.time_scale)
    if timeline is None:
        return None
    hierarchy = config.build_hierarchy(config.load_robot())
    groups = {info.name: info.group for info in set_task_infos(hierarchy)}
    bands = tuple(
        TaskBand(
            t.name,
            groups[t.name],
            t.thresholds.safety_lower,
            t.thresholds.safety_upper,
            t.thresholds.activation_lower,
            t.thresholds.activation_upper,
        )
        for t in hierarchy.set_tasks
    )
    cps = tuple(getattr(t, "frame", t.name) for t in hierarchy.set_tasks if groups[t.name] == "obstacles")
    return ClaimContext(kind, bands, cps, timeline, config.waypoints.tolerance_m)


# --------------------------------------------------------------------------------- helpers


def _col(steps: pd.DataFrame, name: str) -> np.ndarray:
    if name not in steps.columns:
        return np.full(len(steps), np.nan)
    return steps[name].to_numpy(dtype=float, na_value=np.nan)


def activated(steps: pd.DataFrame, task: TaskBand) -> np.ndarray:
    """Steps where σ (column ``sigma:<name>``) is in the activation band of eq. 7."""
    sigma = _col(steps, f"sigma:{task.name}")
    with np.errstate(invalid="ignore"):
        return np.isfinite(sigma) & ((sigma <= task.activation_lower) | (sigma >= task.activation_upper))


def _safety_sigma(steps: pd.DataFrame, task: TaskBand) -> np.ndarray:
    truth = f"truth:{task.name}"
    return (
        _col(steps, truth)
        if task.group == "obstacles" and truth in steps.columns
        else _col(steps, f"sigma:{task.name}")
    )


def _worst_margin(steps: pd.DataFrame, tasks: Sequence[TaskBand]) -> tuple[float, str | None, float | None]:
    """Smallest safety margin over ``tasks`` and steps, the task and the time [s]."""
    best: tuple[float, str | None, float | None] = (math.inf, None, None)
    t = _col(steps, "t")
    for task in tasks:
        m = margins(_safety_sigma(steps, task), task.safety_lower, task.safety_upper)
        if not np.any(np.isfinite(m)):
            continue
        k = int(np.nanargmin(m))
        if m[k] < best[0]:
            best = (float(m[k]), task.name, float(t[k]))
    return best


def _window(steps: pd.DataFrame, t0: float, t1: float) -> np.ndarray:
    t = _col(steps, "t")
    return (t >= t0 - 1e-9) & (t <= t1 + 1e-9)


def _ee_path_m(steps: pd.DataFrame, mask: np.ndarray) -> float:
    ee = np.column_stack([_col(steps, f"ee_{a}") for a in "xyz"])[mask]
    if len(ee) < 2:
        return 0.0
    return float(np.sum(np.linalg.norm(np.diff(ee, axis=0), axis=1)))


def _short(name: str, control_points: Sequence[str]) -> str:
    return next((cp for cp in control_points if name.endswith(cp)), name)


def _any_obstacle_active(steps: pd.DataFrame, ctx: ClaimContext) -> np.ndarray:
    active = np.zeros(len(steps), dtype=bool)
    for task in ctx.group("obstacles"):
        active |= activated(steps, task)
    return active


def _distances_claim(key: str, steps: pd.DataFrame, ctx: ClaimContext) -> Claim:
    tasks = ctx.group("obstacles")
    worst, name, when = _worst_margin(steps, tasks)
    threshold = min((t.safety_lower for t in tasks), default=math.nan)
    holds = bool(worst >= -VIOLATION_TOLERANCE) if math.isfinite(worst) else True
    dist = threshold + worst if math.isfinite(worst) else math.inf
    where = f" ({_short(name, ctx.control_points)} at {when:.1f} s)" if name else ""
    return Claim(
        key,
        f"the control-point distances stay above the {threshold:g} m threshold",
        holds,
        f"min {dist:.3f} m{where}" if math.isfinite(dist) else "nobody within range",
        {"min_distance_m": dist, "margin_m": worst},
    )


# --------------------------------------------------------------------------------- case 1


def _c1_free_before(steps: pd.DataFrame, ctx: ClaimContext) -> Claim:
    text = (
        "before the person steps in, the arm reaches both waypoints with the person outside the activation thresholds"
    )
    before = _col(steps, "t") < ctx.person.t_move
    err = _col(steps, "ee_error_m")
    wp = steps["waypoint"].to_numpy() if "waypoint" in steps.columns else np.zeros(len(steps), dtype=int)
    with np.errstate(invalid="ignore"):
        reached = sorted({int(w) for w in wp[before & (err < ctx.waypoint_tolerance_m)]})
    closest = math.inf
    outside = True
    for task in ctx.group("obstacles"):
        truth = _safety_sigma(steps, task)[before]
        finite = truth[np.isfinite(truth)]
        if finite.size:
            closest = min(closest, float(finite.min()))
            outside &= bool(np.all(finite > task.activation_lower))
    activations = int(np.count_nonzero(_any_obstacle_active(steps, ctx) & before))
    holds = len(reached) >= 2 and outside and activations == 0
    return Claim(
        "c1_free_before",
        text,
        holds,
        f"0–{ctx.person.t_move:.1f} s: waypoints reached {reached or 'none'}; person at ≥ {closest:.3f} m;"
        f" {activations} steps with an obstacle task active",
        {"waypoints_reached": reached, "min_distance_m": closest, "active_steps": activations},
    )


def _c1_obstacle_tasks(steps: pd.DataFrame, ctx: ClaimContext) -> Claim:
    tasks = ctx.group("obstacles")
    p = ctx.person
    window = _window(steps, p.t_move, p.t_gone)
    active = {t.name: float(np.count_nonzero(activated(steps, t) & window)) for t in tasks}
    dt = float(np.median(np.diff(_col(steps, "t")))) if len(steps) > 1 else 0.0
    wanted = [t.name for t in tasks[1:3]]  # the paper's second and third control points (wrist, hand)
    others = [t.name for t in tasks if t.name not in wanted]
    holds = all(active[n] > 0 for n in wanted) and not any(active[n] > 0 for n in others)
    parts = [f"{_short(n, ctx.control_points)} {active[n] * dt:.1f} s" for n in active]
    return Claim(
        "c1_obstacle_tasks",
        "the wrist and hand obstacle tasks activate (and only those two)",
        holds,
        "active: " + ", ".join(parts),
        {"active_time_s": {n: v * dt for n, v in active.items()}},
    )


def _first_obstacle_activation(steps: pd.DataFrame, ctx: ClaimContext) -> float | None:
    p = ctx.person
    window = _window(steps, p.t_move, p.t_gone)
    hits = np.flatnonzero(_any_obstacle_active(steps, ctx) & window)
    return float(_col(steps, "t")[hits[0]]) if hits.size else None


def _c1_arm_stops(steps: pd.DataFrame, ctx: ClaimContext) -> Claim:
    text = "the arm stops while the obstacle tasks are active"
    first = _first_obstacle_activation(steps, ctx)
    if first is None:
        return Claim("c1_arm_stops", text, False, "no obstacle task activated", {})
    t0, t1 = max(first, ctx.person.t_in) + SETTLE_S, ctx.person.t_leave
    if t1 <= t0:
        return Claim("c1_arm_stops", text, False, f"first activation at {first:.1f} s, too late to stop", {})
    mask = _window(steps, t0, t1)
    path = _ee_path_m(steps, mask)
    speed = path / (t1 - t0)
    ee = np.column_stack([_col(steps, f"ee_{a}") for a in "xyz"])[mask]
    t = _col(steps, "t")[mask]
    net = []  # net EE displacement over each second of the window [m/s]: progress, not chatter
    for start in np.arange(t0, t1 - STOP_WINDOW_S + 1e-9, STOP_WINDOW_S):
        inside = np.flatnonzero((t >= start) & (t <= start + STOP_WINDOW_S))
        if inside.size > 1:
            net.append(float(np.linalg.norm(ee[inside[-1]] - ee[inside[0]])) / STOP_WINDOW_S)
    progress = float(np.median(net)) if net else 0.0
    wp = steps["waypoint"].to_numpy()[mask] if "waypoint" in steps.columns else np.zeros(1)
    switches = int(np.count_nonzero(wp[1:] != wp[:-1])) if wp.size > 1 else 0
    holds = progress < STOPPED_SPEED_MPS and switches == 0
    return Claim(
        "c1_arm_stops",
        text,
        holds,
        f"{t0:.1f}–{t1:.1f} s: EE progress {100.0 * progress:.1f} cm/s (median of 1 s), path"
        f" {100.0 * speed:.1f} cm/s; {switches} waypoint switches",
        {
            "ee_path_m": path,
            "mean_speed_mps": speed,
            "median_progress_mps": progress,
            "waypoint_switches": switches,
            "window_s": [t0, t1],
        },
    )


def _c1_joint4_limit(steps: pd.DataFrame, ctx: ClaimContext) -> Claim:
    text = "joint 4's limit task activates and the joint stops at its threshold"
    task = next((t for t in ctx.group("joint_limits") if t.name.endswith("_4")), None)
    if task is None:
        return Claim("c1_joint4_limit", text, False, "no joint-4 limit task", {})
    active = activated(steps, task)
    t = _col(steps, "t")
    worst, _, when = _worst_margin(steps, [task])
    ever = bool(np.any(active))
    holds = ever and worst >= -VIOLATION_TOLERANCE
    first = f"first at {t[np.flatnonzero(active)[0]]:.1f} s" if ever else "never"
    return Claim(
        "c1_joint4_limit",
        text,
        holds,
        f"activated {first}; safety margin min {worst:+.4f} rad",
        {"activated": ever, "margin_rad": worst, "margin_time_s": when},
    )


def _c1_resumes(steps: pd.DataFrame, ctx: ClaimContext) -> Claim:
    text = "the motion resumes when the person leaves"
    p = ctx.person
    t = _col(steps, "t")
    late = t > p.t_gone + DEACTIVATION_GRACE_S
    still = bool(np.any(_any_obstacle_active(steps, ctx) & late))
    after = t >= p.t_leave
    err = _col(steps, "ee_error_m")
    with np.errstate(invalid="ignore"):
        reached = np.flatnonzero(after & (err < ctx.waypoint_tolerance_m))
    t_reach = float(t[reached[0]]) if reached.size else None
    holds = not still and t_reach is not None
    where = f"waypoint reached at {t_reach:.1f} s" if t_reach is not None else "no waypoint reached"
    return Claim(
        "c1_resumes",
        text,
        holds,
        f"obstacle tasks {'still active' if still else 'inactive'} {DEACTIVATION_GRACE_S:g} s after the person is"
        f" gone ({p.t_gone:.1f} s); {where}",
        {"tasks_still_active": still, "waypoint_reached_s": t_reach, "person_leaves_s": p.t_leave},
    )


# --------------------------------------------------------------------------------- case 2


def _c2_inside_box(steps: pd.DataFrame, ctx: ClaimContext) -> Claim:
    walls = ctx.group("walls")
    p = ctx.person
    window = _window(steps, p.t_move, p.t_gone)
    active = [w.name for w in walls if np.any(activated(steps, w) & window)]
    worst, name, when = _worst_margin(steps, walls)
    inside = worst >= -VIOLATION_TOLERANCE
    holds = bool(active) and inside
    where = f" ({name} at {when:.1f} s)" if name else ""
    return Claim(
        "c2_inside_box",
        "the EE stays inside the virtual box while pushed (the wall tasks activate and stop it)",
        holds,
        f"walls activated: {', '.join(active) or 'none'}; wall margin min {worst:+.4f} m{where}",
        {"walls_activated": active, "margin_m": worst},
    )


def _c2_moves_away(steps: pd.DataFrame, ctx: ClaimContext) -> Claim:
    p = ctx.person
    window = _window(steps, p.t_move, p.t_gone)
    active = bool(np.any(_any_obstacle_active(steps, ctx) & window))
    ee = np.column_stack([_col(steps, f"ee_{a}") for a in "xyz"])
    moved = float(np.nanmax(np.linalg.norm(ee[window] - ee[0], axis=1))) if np.any(window) else 0.0
    holds = active and moved >= MOVED_AWAY_M
    return Claim(
        "c2_moves_away",
        "the obstacle tasks activate and the arm moves away from the person",
        holds,
        f"obstacle task {'activated' if active else 'never activated'}; EE up to {100.0 * moved:.1f} cm from its"
        f" start (≥ {100.0 * MOVED_AWAY_M:g} cm counts)",
        {"activated": active, "ee_displacement_m": moved},
    )


def _c2_chattering(steps: pd.DataFrame, ctx: ClaimContext) -> Claim:
    p = ctx.person
    t = _col(steps, "t")
    active = _any_obstacle_active(steps, ctx)
    toggle = np.concatenate([[False], active[1:] != active[:-1]])
    moving = _window(steps, p.t_move, p.t_gone + DEACTIVATION_GRACE_S)
    while_moving = int(np.count_nonzero(toggle & moving))
    while_still = int(np.count_nonzero(toggle & ~moving))
    span = max(p.t_gone - p.t_move, 1e-9)
    first_still = float(t[np.flatnonzero(toggle & ~moving)[0]]) if while_still else None
    return Claim(
        "c2_chattering",
        "the obstacle tasks chatter only while the person moves",
        while_still == 0,
        f"{while_moving} activation toggles while the person moves ({while_moving / span:.1f} /s),"
        f" {while_still} while still" + (f" (first at {first_still:.1f} s)" if first_still is not None else ""),
        {"toggles_moving": while_moving, "toggles_still": while_still},
    )


def _c2_joint_limits(steps: pd.DataFrame, ctx: ClaimContext) -> Claim:
    worst, name, when = _worst_margin(steps, ctx.group("joint_limits"))
    holds = worst >= -VIOLATION_TOLERANCE
    where = f" ({name} at {when:.1f} s)" if name else ""
    return Claim(
        "c2_joint_limits",
        "the joint positions never exceed their limits",
        holds,
        f"safety margin min {worst:+.4f} rad{where}",
        {"margin_rad": worst},
    )


def _c2_returns(steps: pd.DataFrame, ctx: ClaimContext) -> Claim:
    t = _col(steps, "t")
    err = _col(steps, "ee_error_m")
    after = t >= ctx.person.t_gone
    with np.errstate(invalid="ignore"):
        back = np.flatnonzero(after & (err < ctx.waypoint_tolerance_m))
    t_back = float(t[back[0]]) if back.size else None
    final = float(err[np.isfinite(err)][-1]) if np.any(np.isfinite(err)) else math.nan
    return Claim(
        "c2_returns",
        "the arm returns to its initial position when the person steps away",
        t_back is not None,
        (f"back within {ctx.waypoint_tolerance_m:g} m at {t_back:.1f} s" if t_back is not None else "not back")
        + f"; final error {final:.3f} m",
        {"returned_s": t_back, "final_error_m": final},
    )


CASE1_CLAIMS: tuple[Callable[[pd.DataFrame, ClaimContext], Claim], ...] = (
    _c1_free_before,
    _c1_obstacle_tasks,
    _c1_arm_stops,
    lambda steps, ctx: _distances_claim("c1_distances", steps, ctx),
    _c1_joint4_limit,
    _c1_resumes,
)
CASE2_CLAIMS: tuple[Callable[[pd.DataFrame, ClaimContext], Claim], ...] = (
    _c2_moves_away,
    _c2_inside_box,
    lambda steps, ctx: _distances_claim("c2_distances", steps, ctx),
    _c2_joint_limits,
    _c2_returns,
    _c2_chattering,
)


def check_claims(steps: pd.DataFrame, ctx: ClaimContext) -> list[Claim]:
    """Every claim of the case ``ctx.kind`` measured on one method's per-step table."""
    checks = CASE1_CLAIMS if ctx.kind == "case1" else CASE2_CLAIMS
    steps = steps[steps["t"].notna()].reset_index(drop=True)
    return [check(steps, ctx) for check in checks]


def claims_for_run(
    run_dir: Path, methods: Sequence[str] | None = None, config: Config | None = None
) -> dict[str, list[Claim]]:
    """The claims per method of a run directory (``steps/``); {} for non-case runs.

    Args:
        run_dir: The run directory.
        methods: The methods (default: those of its ``summary.json``).
        config: The run's config (default: the directory's ``config.toml``).
    """
    run_dir = Path(run_dir)
    if config is None:
        config, _ = load_config(run_dir / "config.toml")
    ctx = context_from_config(config)
    if ctx is None:
        return {}
    names = list(methods) if methods is not None else list(load_summary(run_dir).get("methods") or {})
    return {name: check_claims(load_steps(run_dir, name), ctx) for name in names}


# --------------------------------------------------------------------------------- table


def claims_table(columns: Sequence[tuple[str, dict[str, list[Claim]]]]) -> str:
    """Markdown table: one row per (claim, method), one column per label.

    Args:
        columns: ``(label, {method: claims})`` in display order (e.g. the config's speed, each
            method's critical speed, the paper-paced variant). A method missing under a label
            gets "–".
    """
    labels = [label for label, _ in columns]
    order: list[tuple[str, str]] = []
    methods: list[str] = []
    cells: dict[tuple[str, str, str], str] = {}
    for label, per_method in columns:
        for method, claims in per_method.items():
            if method not in methods:
                methods.append(method)
            for c in claims:
                if (c.key, c.claim) not in order:
                    order.append((c.key, c.claim))
                cells[(c.key, method, label)] = ("✓ " if c.holds else "✗ ") + c.measured
    lines = ["| claim | method | " + " | ".join(labels) + " |", "|---|---|" + "---|" * len(labels)]
    for key, text in order:
        for k, method in enumerate(methods):
            row = [cells.get((key, method, label), "–").replace("|", "\\|") for label in labels]
            lines.append(f"| {text if k == 0 else ''} | {method} | " + " | ".join(row) + " |")
    return "\n".join(lines)


def _claim_from_dict(data: dict[str, Any]) -> Claim:
    fixed = {"key", "claim", "holds", "measured"}
    values = {k: v for k, v in data.items() if k not in fixed}
    return Claim(str(data["key"]), str(data["claim"]), bool(data["holds"]), str(data["measured"]), values)


def claims_report(paths: Sequence[Path], labels: Sequence[str] | None = None) -> tuple[str, dict[str, Any]]:
    """The claims table of run directories and critical-speed directories, and its JSON.

    A run directory gives one column (the config's own speeds, stated in the label); a
    critical-speed directory one column with each method at its own critical speed (read from
    ``claims_at_critical.json``; "none held" and the slowest swept speed when no speed held).

    Raises:
        FileNotFoundError: A path is neither kind of directory.
        ValueError: ``labels`` does not match ``paths``.
    """
    if labels and len(labels) != len(paths):
        raise ValueError(f"--label: {len(labels)} labels for {len(paths)} results")
    columns: list[tuple[str, dict[str, list[Claim]]]] = []
    data: dict[str, Any] = {}
    for k, path in enumerate(Path(p) for p in paths):
        if (path / CLAIMS_FILE).is_file():
            stored = json.loads((path / CLAIMS_FILE).read_text(encoding="utf-8"))
            scenario = json.loads((path / DETAIL_FILE).read_text(encoding="utf-8")).get("scenario", path.name)
            label = labels[k] if labels else f"{scenario}, each method's critical speed"
            per_method = {}
            for name, entry in stored.items():
                v = entry.get("speed_mps")
                claims = [_claim_from_dict(c) for c in entry.get("claims") or []]
                prefix = ""
                if v is not None:
                    prefix = f"[{v:.2g} m/s] " if entry.get("critical") else f"[none held; {v:.2g} m/s] "
                per_method[name] = [Claim(c.key, c.claim, c.holds, prefix + c.measured, c.values) for c in claims] or [
                    Claim("critical", "critical speed", False, "no speed held", {})
                ]
            data[label] = stored
        elif (path / "summary.json").is_file():
            config, _ = load_config(path / "config.toml")
            torso, hand = keyframe_speeds(config)
            scenario = load_summary(path).get("scenario", path.name)
            label = labels[k] if labels else f"{scenario} (torso {torso:.2g} m/s, hand {hand:.2g} m/s)"
            per_method = claims_for_run(path)
            data[label] = {m: [c.to_dict() for c in cl] for m, cl in per_method.items()}
        else:
            raise FileNotFoundError(f"{path}: neither a run (summary.json) nor a critical-speed directory")
        columns.append((label, per_method))
    return claims_table(columns), data

"""Registry of the IK methods a scenario can compare, looked up by name (docs/design.md §3).

Names:

* ``tpik``: the project's set-based TPIK (:mod:`tpik.solver`, every default setting);
* ``tpik-paper``: the paper as printed (:data:`tpik.solver.PAPER_SETTINGS`: eq. 4 at every
  level, the largest-norm mode admissible by eqs. 8–9 alone, sec. II-A's damping with
  σ* = ‖σ̃‖/‖q̇‖_max, no gain cap);
* ``tpik-ss``: ``tpik`` with the Siciliano–Slotine cascade at every level;
* ``tpik-no-<deviation>``: ``tpik`` with one of its :data:`tpik.solver.DEVIATIONS` from the
  paper switched off (the ablation, ``tpik-compare ablation``);
* ``hqp-<qp solver>``: the HQP cascade with any qpsolvers backend installed;
* ``mink``: mink with the project's set-based tasks as one custom mink ``Limit`` and a soft,
  weighted return into the safe set (a custom mink ``Task``); ``mink-hard``: the same with hard
  return-rate rows instead of the soft return; ``mink-posture``: ``mink`` with the regularisation
  of mink's arm examples (:data:`qp_baseline.mink_peer.POSTURE_PRESET`), :mod:`qp_baseline.mink_peer`.

:data:`DESCRIPTIONS` says what each name is in one line (``tpik-compare methods``, the README's
method table).

A method whose package cannot be imported is left out of :func:`available_methods`
(qpsolvers' approach to optional backends). Settings of the config (``[methods.settings.<name>]``)
override the preset of the name key by key.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from compare.exceptions import CompareError
from robots import Robot
from tpik.step_result import IkSolver


class UnknownMethod(CompareError, ValueError):
    """The method name is not available; the message lists the available ones."""

    def __init__(self, name: str, available: list[str]) -> None:
        super().__init__(f"unknown method '{name}'; available: {', '.join(available)}")
        self.name = name


ABLATION_PREFIX = "tpik-no-"
"""``tpik-no-<deviation>``: ``tpik`` with one deviation from the paper switched off."""

DESCRIPTIONS: dict[str, str] = {
    "tpik-paper": "the paper as printed: eq. 4 at every level, the largest-norm mode admissible by eqs. 8–9 "
    "alone, the damping of sec. II-A with σ* = ‖σ̃‖/‖q̇‖_max, no gain cap",
    "tpik": "the project's set-based TPIK: tpik-paper plus the deviations of tpik.solver.DEVIATIONS "
    "(compensated levels, fewest-active mode choice, return-rate condition, gain cap, σ* from the reference)",
    "tpik-ss": "tpik with the Siciliano–Slotine cascade at every level",
    f"{ABLATION_PREFIX}<deviation>": "tpik with one deviation from the paper switched off (the ablation)",
    "hqp-<solver>": "the same levels as a lexicographic cascade of QPs (set tasks as slack-relaxed rate rows, "
    "hard joint box), any qpsolvers backend",
    "mink": "mink (its kinematics, FrameTask, ConfigurationLimit, VelocityLimit) with the project's set tasks "
    "as one custom mink Limit that the zero step satisfies and a custom weighted Task pulling a task past its "
    "safety threshold back (costs 1000/100/10 for joint limits/walls/obstacles vs 1 for the EE task, "
    "level_cost_ratio 10): a build of the project's hierarchy in mink, not a mink idiom",
    "mink-hard": "mink with the same limits but hard return-rate rows instead of the soft return "
    "(the project's earlier adapter): no solution is a FAILED step",
    "mink-posture": "mink set up as mink's arm examples set up a redundant arm: the tasks and limits of mink plus "
    "a PostureTask toward the start posture (cost 1e-2), lm_damping 1.0 on the frame task and solver damping "
    "1e-3 (values of mink's franka_emika_panda.py and arm_iiwa.py examples)",
}
"""What each method name (or name pattern) is, in one line (plain text, printed by ``tpik-compare methods``)."""


def describe(name: str) -> str:
    """The :data:`DESCRIPTIONS` line of ``name`` (``hqp-*`` and ``tpik-no-*`` from their pattern); "" if none."""
    if name in DESCRIPTIONS:
        return DESCRIPTIONS[name]
    if name.startswith(ABLATION_PREFIX):
        return f"tpik with its deviation '{name.removeprefix(ABLATION_PREFIX)}' switched off (the ablation)"
    if name.startswith("hqp-"):
        return DESCRIPTIONS["hqp-<solver>"].replace("any qpsolvers backend", f"backend {name.removeprefix('hqp-')}")
    return ""


def tpik_presets() -> dict[str, dict[str, Any]]:
    """TPIK method names and the settings each stands for (before the config's own settings)."""
    from tpik.solver import DEVIATIONS, PAPER_SETTINGS  # Deferred: optional method (docstring)

    presets: dict[str, dict[str, Any]] = {"tpik": {}, "tpik-paper": dict(PAPER_SETTINGS), "tpik-ss": {"variant": "ss"}}
    for name, dev in DEVIATIONS.items():
        presets[f"{ABLATION_PREFIX}{name}"] = {dev.setting: dev.paper}
    return presets


def ablation_methods() -> list[str]:
    """``tpik``, ``tpik-paper`` and every ``tpik-no-<deviation>``: the methods of the ablation."""
    return ["tpik", "tpik-paper"] + [n for n in tpik_presets() if n.startswith(ABLATION_PREFIX)]


def available_methods() -> list[str]:
    """Every method name :func:`make_method` accepts on this installation."""
    names: list[str] = []
    try:
        names += list(tpik_presets())
    except ImportError:
        pass
    try:
        from qp_baseline.hqp import available_qp_solvers  # Deferred: optional method (docstring)

        names += [f"hqp-{s}" for s in available_qp_solvers()]
    except ImportError:
        pass
    try:
        from qp_baseline.mink_peer import MINK_METHODS  # Deferred: optional method (docstring)

        names += list(MINK_METHODS)
    except ImportError:
        pass
    return names


def make_method(name: str, robot: Robot, settings: Mapping[str, Any] | None = None) -> IkSolver:
    """Build the solver registered as ``name`` with its settings.

    Raises:
        UnknownMethod: ``name`` is not available (the message lists what is).
    """
    opts = dict(settings or {})
    if name == "tpik" or name.startswith("tpik-"):
        from tpik.solver import TpikSettings, TpikSolver  # Deferred: optional method (docstring)

        presets = tpik_presets()
        if name not in presets:
            raise UnknownMethod(name, available_methods())
        return TpikSolver(robot, TpikSettings.from_dict({**presets[name], **opts}), name=name)
    if name.startswith("hqp-"):
        from qp_baseline.hqp import HqpSolver, available_qp_solvers  # Deferred: optional method (docstring)

        solver = name.removeprefix("hqp-")
        if solver not in available_qp_solvers():
            raise UnknownMethod(name, available_methods())
        return HqpSolver(robot, solver=solver, settings=opts, name=name)
    if name.startswith("mink"):
        from qp_baseline.mink_peer import MINK_METHODS, MinkSolver  # Deferred: optional method (docstring)

        if name not in MINK_METHODS:
            raise UnknownMethod(name, available_methods())
        formulation, preset = MINK_METHODS[name]
        return MinkSolver(robot, settings={**preset, **opts}, name=name, formulation=formulation)
    raise UnknownMethod(name, available_methods())

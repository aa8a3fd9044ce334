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
* ``mink``: mink as its users run it; ``mink-hard``: the strict variant (hard return-rate
  rows), :mod:`qp_baseline.mink_peer`.

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


def tpik_presets() -> dict[str, dict[str, Any]]:
    """TPIK method names and the settings each stands for (before the config's own settings)."""
    from tpik.solver import DEVIATIONS, PAPER_SETTINGS

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
        from qp_baseline.hqp import available_qp_solvers

        names += [f"hqp-{s}" for s in available_qp_solvers()]
    except ImportError:
        pass
    try:
        from qp_baseline.mink_peer import FORMULATIONS

        names += list(FORMULATIONS.values())
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
        from tpik.solver import TpikSettings, TpikSolver

        presets = tpik_presets()
        if name not in presets:
            raise UnknownMethod(name, available_methods())
        return TpikSolver(robot, TpikSettings.from_dict({**presets[name], **opts}), name=name)
    if name.startswith("hqp-"):
        from qp_baseline.hqp import HqpSolver, available_qp_solvers

        solver = name.removeprefix("hqp-")
        if solver not in available_qp_solvers():
            raise UnknownMethod(name, available_methods())
        return HqpSolver(robot, solver=solver, settings=opts, name=name)
    if name in ("mink", "mink-hard"):
        from qp_baseline.mink_peer import FORMULATIONS, MinkSolver

        formulation = next(f for f, method in FORMULATIONS.items() if method == name)
        return MinkSolver(robot, settings=opts, name=name, formulation=formulation)
    raise UnknownMethod(name, available_methods())

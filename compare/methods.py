"""Registry of the IK methods a scenario can compare, looked up by name.

Names: ``tpik`` (paper solver), ``tpik-<variant>``, ``hqp-<qp solver>`` (any qpsolvers
backend installed), ``mink``. A method whose package cannot be imported is left out of
:func:`available_methods` (qpsolvers' approach to optional backends).
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


def available_methods() -> list[str]:
    """Every method name :func:`make_method` accepts on this installation."""
    names: list[str] = []
    try:
        from tpik.solver import TpikSolver

        names += ["tpik"] + [f"tpik-{v}" for v in TpikSolver.VARIANTS]
    except ImportError:
        pass
    try:
        from qp_baseline.hqp import available_qp_solvers

        names += [f"hqp-{s}" for s in available_qp_solvers()]
    except ImportError:
        pass
    try:
        import qp_baseline.mink_peer  # noqa: F401

        names.append("mink")
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

        variant = name.partition("-")[2] or opts.pop("variant", TpikSolver.VARIANTS[0])
        if variant not in TpikSolver.VARIANTS:
            raise UnknownMethod(name, available_methods())
        return TpikSolver(robot, TpikSettings.from_dict({**opts, "variant": variant}), name=name)
    if name.startswith("hqp-"):
        from qp_baseline.hqp import HqpSolver, available_qp_solvers

        solver = name.removeprefix("hqp-")
        if solver not in available_qp_solvers():
            raise UnknownMethod(name, available_methods())
        return HqpSolver(robot, solver=solver, settings=opts, name=name)
    if name == "mink":
        from qp_baseline.mink_peer import MinkSolver

        return MinkSolver(robot, settings=opts, name=name)
    raise UnknownMethod(name, available_methods())

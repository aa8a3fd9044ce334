"""Hierarchical-QP baseline over the same tpik hierarchy, and the mink peer.

* :class:`~qp_baseline.hqp.HqpSolver`: lexicographic cascade of QPs, one per priority level, any
  backend of :func:`~qp_baseline.hqp.available_qp_solvers` through qpsolvers;
* :class:`~qp_baseline.mink_peer.MinkSolver`: the same tasks handed to ``mink.solve_ik``.

Both expose ``name`` and ``solve(hierarchy, kin, dt) -> StepResult``. The mink peer is imported
on demand (``qp_baseline.mink_peer``) so that the HQP baseline does not need mink.
"""

from qp_baseline.exceptions import HqpError, InvalidSettings, NoSolutionFound, UnknownSolver
from qp_baseline.hqp import HqpSettings, HqpSolver, available_qp_solvers

__all__ = [
    "HqpError",
    "HqpSettings",
    "HqpSolver",
    "InvalidSettings",
    "NoSolutionFound",
    "UnknownSolver",
    "available_qp_solvers",
]

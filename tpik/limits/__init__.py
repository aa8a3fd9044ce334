r"""Joint limits as objects every method reads (mink's limits idea): one file per limit.

Each :class:`Limit` gives a per-joint velocity box at a state (:meth:`Limit.compute_box`) and the
rows :math:`G\dot q \le h` it stands for (:meth:`Limit.compute_qp_inequalities`). HQP takes the
composed box (:func:`compose_box`) as its hard bounds, the mink peer the stacked rows
(:func:`stack_inequalities`), TPIK scales its velocity into the box (:func:`scale_into_box`).
Adding a limit is one subclass in one file (``docs/extending.md``).
"""

from tpik.limits.acceleration_limit import AccelerationLimit
from tpik.limits.limit import Box, Constraint, Limit, compose_box, scale_into_box, stack_inequalities
from tpik.limits.position_limit import PositionLimit
from tpik.limits.velocity_limit import VelocityLimit

__all__ = [
    "AccelerationLimit",
    "Box",
    "Constraint",
    "Limit",
    "PositionLimit",
    "VelocityLimit",
    "compose_box",
    "scale_into_box",
    "stack_inequalities",
]

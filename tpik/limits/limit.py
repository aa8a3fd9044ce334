r"""The limit interface: a per-joint velocity box and the inequality rows it stands for.

A limit (mink's ``Limit`` idea, written for velocities) restricts the joint velocity command
:math:`\dot q` [rad/s] of one control step of period :math:`dt` [s] to a box

.. math::
    \underline b(q, dt) \le \dot q \le \overline b(q, dt),

which the QP methods read as the rows :math:`G\dot q \le h` (:meth:`Limit.compute_qp_inequalities`,
a finite upper bound gives :math:`e_i^T\dot q \le \overline b_i`, a finite lower one
:math:`-e_i^T\dot q \le -\underline b_i`) and TPIK as the box its final velocity scaling keeps
:math:`\dot q` in (:func:`scale_into_box`). Every limit of this project is such a box: the
analytic solver can respect a box by scaling, not general rows.

Several limits are composed *in order* (:func:`compose_box`): each later limit's box is clipped
into the box of the earlier ones, so the composition is never empty. The first limits are the
physical ones (velocity, then acceleration); the joint position box comes last, so that a joint
already outside its position limits is driven back no faster than the velocity limits allow
(the hard box of :mod:`qp_baseline.hqp`).
"""

from __future__ import annotations

import abc
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np


class Constraint(NamedTuple):
    r"""Rows :math:`G\dot q \le h` of a limit [rad/s]; G shape (r, n), h shape (r,)."""

    G: np.ndarray
    h: np.ndarray


class Box(NamedTuple):
    r"""Per-joint bounds :math:`lower \le \dot q \le upper` [rad/s], each shape (n,); ±inf: none."""

    lower: np.ndarray
    upper: np.ndarray


class Limit(abc.ABC):
    """A restriction of the joint velocity command to a box that depends on the state.

    Subclasses implement :meth:`compute_box`; stateful limits (e.g. on acceleration) also
    :meth:`observe`, which every solver calls with the velocity it commanded.
    """

    @abc.abstractmethod
    def compute_box(self, q: np.ndarray, dt: float) -> Box:
        r"""The box :math:`\underline b \le \dot q \le \overline b` [rad/s] at configuration ``q`` [rad].

        Args:
            q: Joint configuration [rad]. Shape (n,).
            dt: Control period [s], > 0.

        Returns:
            New arrays (the caller may change them in place).
        """

    def compute_qp_inequalities(self, q: np.ndarray, dt: float) -> Constraint:
        r"""The box as rows :math:`G\dot q \le h` [rad/s]: upper rows first, infinite bounds left out."""
        lower, upper = self.compute_box(q, dt)
        n = lower.shape[0]
        eye = np.eye(n)
        up, lo = np.isfinite(upper), np.isfinite(lower)
        return Constraint(np.vstack([eye[up], -eye[lo]]), np.concatenate([upper[up], -lower[lo]]))

    def observe(self, qdot: np.ndarray) -> None:  # noqa: B027 - optional hook, no-op by default
        """Note the velocity the solver commanded this step [rad/s] (stateful limits only)."""

    def __repr__(self) -> str:
        return f"{type(self).__name__}()"


def compose_box(limits: Sequence[Limit], q: np.ndarray, dt: float) -> Box:
    r"""The boxes of ``limits`` composed in order: each one clipped into the earlier ones'.

    With :math:`[\underline c, \overline c]` the composition so far and :math:`[\underline b,
    \overline b]` the next box, the result is :math:`[\mathrm{clip}(\underline b, \underline c,
    \overline c), \mathrm{clip}(\overline b, \underline c, \overline c)]`: the intersection when it
    is not empty, else the end of :math:`[\underline c, \overline c]` nearest to the next box.

    Raises:
        ValueError: ``limits`` is empty.
    """
    if not limits:
        raise ValueError("compose_box needs at least one limit")
    lower, upper = limits[0].compute_box(q, dt)
    for limit in limits[1:]:
        lo, hi = limit.compute_box(q, dt)
        np.maximum(lo, lower, out=lo)
        np.minimum(lo, upper, out=lo)
        np.minimum(hi, upper, out=hi)
        np.maximum(hi, lower, out=hi)
        lower, upper = lo, hi
    return Box(lower, upper)


def stack_inequalities(limits: Sequence[Limit], q: np.ndarray, dt: float) -> Constraint:
    r"""Every limit's rows stacked, in order (the QP form of all of them at once)."""
    parts = [limit.compute_qp_inequalities(q, dt) for limit in limits]
    n = q.shape[0]
    if not parts:
        return Constraint(np.zeros((0, n)), np.zeros(0))
    return Constraint(np.vstack([p.G for p in parts]), np.concatenate([p.h for p in parts]))


def scale_into_box(qdot: np.ndarray, box: Box) -> tuple[np.ndarray, float]:
    r"""Pull ``qdot`` into ``box`` along the segment from the box's point nearest zero.

    With the anchor :math:`a = \mathrm{clip}(0, \underline b, \overline b)` the result is
    :math:`a + s(\dot q - a)` with the largest :math:`s \in [0, 1]` that lies in the box; when
    the box holds zero (velocity limits) that is one scale factor on :math:`\dot q`, its
    direction kept (the paper's final scaling).

    Returns:
        (the velocity in the box, s).
    """
    lower, upper = box
    anchor = np.minimum(np.maximum(0.0, lower), upper)
    step = qdot - anchor
    s = 1.0
    with np.errstate(divide="ignore", invalid="ignore"):
        room = np.where(step > 0.0, (upper - anchor) / step, np.where(step < 0.0, (lower - anchor) / step, np.inf))
    worst = float(np.min(room)) if room.size else np.inf
    if worst < 1.0:
        s = max(worst, 0.0)
    if s == 1.0:
        return qdot, 1.0
    return anchor + s * step, s

r"""σ of the built-in set tasks in one compiled call (numba), numpy's arithmetic bit for bit.

A wall's σ is :math:`n^T p - d` and an obstacle task's :math:`\|O - P\| - g`, both a numpy dot
of two 3-vectors in the tasks' own ``compute_value``, here :func:`~compare.loop.numpy_dot.dot3`
in the order numpy uses on the machine, so the σ equal the tasks' own
(``tests/compare/loop/test_recorder.py``); where numpy's dot is neither chain, the loop asks
every task itself.
"""

from __future__ import annotations

import numba
import numpy as np

from compare.loop.numpy_dot import dot3

KIND_GIVEN = 0
"""σ already written by the caller (a task without a compiled σ)."""
KIND_JOINT = 1
"""A joint limit: σ = q[index]."""
KIND_WALL = 2
"""A wall: σ = n·P[index] − d, n in ``spec[k, 2:5]``, d in ``spec[k, 5]``."""
KIND_OBSTACLE = 3
"""An obstacle distance: σ = ‖O − P[index]‖ − g, O in ``spec[k, 2:5]`` (NaN: none, σ = +inf), g in ``spec[k, 5]``."""

SPEC_COLUMNS = 8
"""Columns of a task's row of ``spec``: kind, index, three values, a scalar, σ_{a,l}, σ_{a,u}."""


@numba.njit(cache=True, nogil=True)
def set_task_sigmas(
    q: np.ndarray, points: np.ndarray, spec: np.ndarray, sigma: np.ndarray, near: np.ndarray, fused: bool
) -> int:
    """σ of every task into ``sigma`` and the indices of those at or past an activation threshold into ``near``.

    Args:
        q: Joint angles [rad], shape (n,).
        points: Frame origins [m], shape (F, 3).
        spec: One row per task (:data:`SPEC_COLUMNS`): kind, index, values, scalar, σ_{a,l}, σ_{a,u}.
        sigma: σ per task, shape (K,); a :data:`KIND_GIVEN` entry is read, the others written.
        near: Receives the indices of the finite σ with σ ≥ σ_{a,u} or σ ≤ σ_{a,l}, in order.
        fused: numpy's dot fuses its multiply-adds (:data:`~compare.loop.numpy_dot.NUMPY_DOT_FUSED`).

    Returns:
        How many indices were written to ``near``.
    """
    count = 0
    for k in range(spec.shape[0]):
        kind = int(spec[k, 0])
        idx = int(spec[k, 1])
        if kind == KIND_JOINT:
            if idx < 0 or idx >= q.shape[0]:
                raise IndexError("a joint limit's joint is not a joint of q")
            s = q[idx]
        elif kind == KIND_WALL:
            p = points[idx]
            s = dot3(spec[k, 2], spec[k, 3], spec[k, 4], p[0], p[1], p[2], fused) - spec[k, 5]
        elif kind == KIND_OBSTACLE:
            if np.isnan(spec[k, 2]):
                s = np.inf
            else:
                p = points[idx]
                d0, d1, d2 = spec[k, 2] - p[0], spec[k, 3] - p[1], spec[k, 4] - p[2]
                dist = np.sqrt(dot3(d0, d1, d2, d0, d1, d2, fused))
                s = (0.0 if dist < 1e-9 else dist) - spec[k, 5]
        else:
            s = sigma[k]
        sigma[k] = s
        if (s >= spec[k, 7] or s <= spec[k, 6]) and np.isfinite(s):
            near[count] = k
            count += 1
    return count

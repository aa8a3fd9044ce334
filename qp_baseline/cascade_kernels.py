r"""Compiled helpers of the HQP cascade (:mod:`qp_baseline.hqp`).

They hold the per-step arithmetic that is neither a backend call nor a product feeding one.

Each kernel does in one call what took a handful of NumPy calls on vectors of a few entries;
every number that reaches a QP backend is computed as before, entry by entry (copies, one
product and one sum per entry), so the level QPs are bit for bit the same.
"""

from __future__ import annotations

import numba
import numpy as np

from tpik.evaluation import EQ_ERROR, EQ_FEEDFORWARD, EQ_GAIN, EQ_JAC


@numba.njit(cache=True, nogil=True)
def equality_rows(
    eq_out: np.ndarray, eq_in: np.ndarray, eq_ptr: np.ndarray, dt: float, gain_cap: bool, J: np.ndarray, r: np.ndarray
) -> bool:
    r"""Every equality row's Jacobian into ``J``, its CLIK reference into ``r``.

    The reference is :math:`r = \dot\sigma_d + K\tilde\sigma` (paper eq. 2), with the gain K of
    each task capped at 1/dt with ``gain_cap`` (:func:`tpik.reference.effective_gain`);
    ``eq_out``, ``eq_in``, ``eq_ptr`` are the buffers of an evaluated :class:`tpik.evaluation.TaskEvaluation`.

    Returns:
        Whether every entry of ``J`` and ``r`` is finite.
    """
    finite = True
    k_max = 1.0 / dt
    for e in range(eq_ptr.shape[0] - 1):
        k = eq_in[e, EQ_GAIN]
        if gain_cap:
            k = k if k < k_max else k_max
        for i in range(eq_ptr[e], eq_ptr[e + 1]):
            r[i] = eq_out[i, EQ_FEEDFORWARD] + k * eq_out[i, EQ_ERROR]
            finite = finite and np.isfinite(r[i])
            for j in range(J.shape[1]):
                J[i, j] = eq_out[i, EQ_JAC + j]
                finite = finite and np.isfinite(J[i, j])
    return finite


def warm_up(nq: int) -> None:
    """Load the kernels into this process: no control step compiles them."""
    if not equality_rows.signatures:
        equality_rows(
            np.zeros((0, EQ_JAC + nq)),
            np.zeros((0, EQ_GAIN + 1)),
            np.zeros(1, dtype=np.int64),
            0.01,
            True,
            np.zeros((0, nq)),
            np.zeros(0),
        )

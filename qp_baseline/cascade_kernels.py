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


@numba.njit(cache=True, nogil=True)
def clip_into(v: np.ndarray, lb: np.ndarray, ub: np.ndarray) -> None:
    r"""``v`` clipped into the box in place: :math:`v \leftarrow \min(\max(v, lb), ub)`.

    The same numbers as ``np.maximum(v, lb, out=v)`` then ``np.minimum(v, ub, out=v)``.
    """
    for i in range(v.shape[0]):
        if v[i] < lb[i]:
            v[i] = lb[i]
        if v[i] > ub[i]:
            v[i] = ub[i]


@numba.njit(cache=True, nogil=True)
def raise_to(h: np.ndarray, g: np.ndarray) -> None:
    r""":math:`h \leftarrow \max(h, g)` in place (as ``np.maximum(h, g, out=h)``)."""
    for i in range(h.shape[0]):
        if h[i] < g[i]:
            h[i] = g[i]


@numba.njit(cache=True, nogil=True)
def feasible(v: np.ndarray, lb: np.ndarray, ub: np.ndarray, Gv: np.ndarray, h: np.ndarray) -> bool:
    r"""Whether :math:`lb \le v \le ub` and :math:`Gv \le h` (``Gv`` the product, computed by the caller)."""
    for i in range(v.shape[0]):
        if not (v[i] >= lb[i] and v[i] <= ub[i]):
            return False
    for r in range(h.shape[0]):
        if not Gv[r] <= h[r]:
            return False
    return True


@numba.njit(cache=True, nogil=True)
def binds(v: np.ndarray, lb: np.ndarray, ub: np.ndarray, Gv: np.ndarray, h: np.ndarray, tol: float) -> bool:
    r"""Whether a bound or a row is within ``tol`` of binding at ``v``.

    That is :math:`v_i \le lb_i + tol`, :math:`v_i \ge ub_i - tol` or :math:`(Gv)_r \ge h_r - tol`
    for some i or r (``Gv`` the product, computed by the caller).
    """
    for i in range(v.shape[0]):
        if v[i] <= lb[i] + tol or v[i] >= ub[i] - tol:
            return True
    for r in range(h.shape[0]):
        if Gv[r] >= h[r] - tol:
            return True
    return False


@numba.njit(cache=True, nogil=True)
def zero_feasible(lb: np.ndarray, ub: np.ndarray, h: np.ndarray) -> bool:
    r"""Whether :math:`\dot q = 0` meets the box and the rows :math:`G\dot q \le h`.

    That is :math:`lb \le 0 \le ub` and :math:`h \ge 0`.
    """
    for i in range(lb.shape[0]):
        if lb[i] > 0.0 or ub[i] < 0.0:
            return False
    for r in range(h.shape[0]):
        if not h[r] >= 0.0:
            return False
    return True


@numba.njit(cache=True, nogil=True)
def level_objective(
    P: np.ndarray, q: np.ndarray, x: np.ndarray, qd: np.ndarray, at_zero: bool, offset: float, eps: float
) -> float:
    r"""The level objective :math:`\tfrac12(\|J\dot q - r\|^2 + \|w\|^2)` of an answer x = [z; w] with Z = I.

    It is :math:`f(x) + c - \tfrac12\epsilon\|\dot q\|^2` with :math:`f(x) = x^T(\tfrac12 Px + q)`,
    :math:`\dot q = q_d + z` (:math:`z` alone when ``at_zero``: :math:`q_d = 0`) and the constant
    ``offset`` :math:`c = \tfrac12\|Jq_d - r\|^2 + \tfrac12\epsilon\|q_d\|^2`.
    """
    f = 0.0
    for i in range(x.shape[0]):
        px = 0.0
        for j in range(x.shape[0]):
            px += P[i, j] * x[j]
        f += x[i] * (0.5 * px + q[i])
    qq = 0.0
    for i in range(qd.shape[0]):
        v = x[i] if at_zero else qd[i] + x[i]
        qq += v * v
    return f + offset - 0.5 * eps * qq


def warm_up(nq: int) -> None:
    """Load the kernels into this process: no control step compiles them."""
    v = np.zeros(nq)
    clip_into(v, v, v)
    raise_to(v, v)
    feasible(v, v, v, v, v)
    binds(v, v, v, v, v, 0.0)
    zero_feasible(v, v, v)
    level_objective(np.zeros((nq, nq)), v, v, v, True, 0.0, 0.0)
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

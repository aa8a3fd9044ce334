r"""Damped least squares with the paper's dynamic damping (sec. II-A), in Gram coordinates.

The solver never inverts a Jacobian directly. Every velocity the cascade produces is a
combination of the task rows, :math:`\dot q = A^T z`, so each level only needs small symmetric
matrices built from the Gram matrix :math:`G = AA^T` of the stacked rows: for a level whose
(projected) Jacobian is :math:`B`, :math:`S = BB^T` (m × m, m ≤ 6 in practice) and

.. math::
    B^\# r = B^T (BB^T + \lambda^2 I_m)^{-1} r = B^T y,\qquad y = (S + \lambda^2 I_m)^{-1} r

whose eigenvalues are the squared singular values of ``B``. Matrices here are Python lists:
for such sizes plain floats are faster than NumPy calls (each costs about a microsecond).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.linalg import lapack

_TWO_PI_3 = 2.0 * math.pi / 3.0


def dynamic_damping(sigma_min: float, sigma_star: float) -> float:
    r"""Damping factor λ of the paper (sec. II-A).

    .. math::
        \lambda = \begin{cases}
            0 & \sigma_{\min} \ge \sigma^* \\
            \sqrt{\sigma_{\min}(\sigma^* - \sigma_{\min})} & \sigma^*/2 \le \sigma_{\min} < \sigma^* \\
            \sigma^*/2 & \sigma_{\min} < \sigma^*/2
        \end{cases}

    With this λ the damped gain :math:`s/(s^2+\lambda^2)` of every singular value
    ``s ≥ σ_min`` is at most :math:`1/\sigma^*`, so :math:`\|B^\# r\| \le \|r\|/\sigma^*`.
    λ is continuous in :math:`\sigma_{\min}`.

    Args:
        sigma_min: Smallest singular value of the inverted matrix.
        sigma_star: :math:`\sigma^* = \|r\| / \|\dot q\|_{\max}`.

    Returns:
        λ ≥ 0, in the unit of the singular values.
    """
    if sigma_min >= sigma_star:
        return 0.0
    if sigma_min >= 0.5 * sigma_star:
        return math.sqrt(sigma_min * (sigma_star - sigma_min))
    return 0.5 * sigma_star


def min_eigenvalue(S: list[list[float]]) -> float:
    """Smallest eigenvalue of a small symmetric matrix (closed form up to 3 × 3).

    Args:
        S: Symmetric matrix as nested lists. Shape (m, m).

    Returns:
        The smallest eigenvalue (may be slightly negative for a singular PSD matrix).
    """
    m = len(S)
    if m == 1:
        return S[0][0]
    if m == 2:
        a, b, c = S[0][0], S[0][1], S[1][1]
        return 0.5 * (a + c) - math.sqrt(0.25 * (a - c) ** 2 + b * b)
    if m == 3:
        # Trigonometric solution of the characteristic cubic of a symmetric 3 × 3 matrix.
        a, b, c = S[0][0], S[1][1], S[2][2]
        d, e, f = S[0][1], S[0][2], S[1][2]
        off = d * d + e * e + f * f
        q = (a + b + c) / 3.0
        a0, b0, c0 = a - q, b - q, c - q
        p2 = a0 * a0 + b0 * b0 + c0 * c0 + 2.0 * off
        if p2 <= 1e-300:
            return q
        p = math.sqrt(p2 / 6.0)
        det = a0 * (b0 * c0 - f * f) - d * (d * c0 - f * e) + e * (d * f - b0 * e)
        half = det / (2.0 * p * p * p)
        half = -1.0 if half < -1.0 else (1.0 if half > 1.0 else half)
        phi = math.acos(half) / 3.0
        return q + 2.0 * p * math.cos(phi + _TWO_PI_3)
    return float(np.linalg.eigvalsh(np.array(S))[0])


def cholesky_solve(S: list[list[float]], shift: float, r: list[float]) -> list[float] | None:
    r"""Solve :math:`(S + \text{shift}\,I) y = r` by Cholesky; None if not positive definite.

    Args:
        S: Symmetric matrix as nested lists. Shape (m, m).
        shift: Added to the diagonal (λ²).
        r: Right-hand side. Shape (m,).
    """
    m = len(r)
    L: list[list[float]] = []
    for i in range(m):
        Si = S[i]
        row: list[float] = []
        for j in range(i):
            Lj = L[j]
            acc = Si[j]
            for k in range(j):
                acc -= row[k] * Lj[k]
            row.append(acc / Lj[j])
        d = Si[i] + shift
        for k in range(i):
            d -= row[k] * row[k]
        if not d > 0.0:
            return None
        row.append(math.sqrt(d))
        L.append(row)
    w = forward(L, r)
    return backward(L, w)


def forward(L: list[list[float]], b: list[float]) -> list[float]:
    """Solve ``L w = b`` for lower-triangular ``L`` (row ``j`` holds ``j + 1`` entries)."""
    w: list[float] = []
    for j, Lj in enumerate(L):
        acc = b[j]
        for k in range(j):
            acc -= Lj[k] * w[k]
        w.append(acc / Lj[j])
    return w


def backward(L: list[list[float]], w: list[float]) -> list[float]:
    """Solve ``Lᵀ u = w`` for lower-triangular ``L``."""
    m = len(w)
    u = [0.0] * m
    for j in range(m - 1, -1, -1):
        acc = w[j]
        for k in range(j + 1, m):
            acc -= L[k][j] * u[k]
        u[j] = acc / L[j][j]
    return u


def _solve_small(S: list[list[float]], shift: float, r: list[float]) -> list[float] | None:
    """Straight-line Cholesky solve of ``(S + shift I) y = r`` for m = 2 or 3; None if not PD."""
    if len(r) == 2:
        a = S[0][0] + shift
        if not a > 0.0:
            return None
        l00 = math.sqrt(a)
        l10 = S[1][0] / l00
        d = S[1][1] + shift - l10 * l10
        if not d > 0.0:
            return None
        l11 = math.sqrt(d)
        w0 = r[0] / l00
        w1 = (r[1] - l10 * w0) / l11
        y1 = w1 / l11
        return [(w0 - l10 * y1) / l00, y1]
    a = S[0][0] + shift
    if not a > 0.0:
        return None
    l00 = math.sqrt(a)
    l10 = S[1][0] / l00
    l20 = S[2][0] / l00
    d = S[1][1] + shift - l10 * l10
    if not d > 0.0:
        return None
    l11 = math.sqrt(d)
    l21 = (S[2][1] - l20 * l10) / l11
    d = S[2][2] + shift - l20 * l20 - l21 * l21
    if not d > 0.0:
        return None
    l22 = math.sqrt(d)
    w0 = r[0] / l00
    w1 = (r[1] - l10 * w0) / l11
    w2 = (r[2] - l20 * w0 - l21 * w1) / l22
    y2 = w2 / l22
    y1 = (w1 - l21 * y2) / l11
    return [(w0 - l10 * y1 - l20 * y2) / l00, y1, y2]


def gram_dls(
    S: list[list[float]], r: list[float], velocity_norm_max: float, rank_tol: float
) -> tuple[list[float], float]:
    r"""Damped least squares in Gram coordinates: :math:`y = (S + \lambda^2 I)^{-1} r`.

    ``S = BBᵀ`` for the matrix ``B`` the level inverts; the caller forms :math:`B^T y`. λ is
    :func:`dynamic_damping` of :math:`\sigma_{\min}(B) = \sqrt{\lambda_{\min}(S)}` and
    :math:`\sigma^* = \|r\|/\|\dot q\|_{\max}`. Directions whose singular value is at or below
    ``rank_tol`` are dropped (their damped gain is zero), so a rank-deficient ``B`` with
    λ = 0 never divides by zero.

    Args:
        S: :math:`BB^T` as nested lists. Shape (m, m).
        r: Level reference [task unit/s]. Shape (m,).
        velocity_norm_max: :math:`\|\dot q\|_{\max}` [rad/s].
        rank_tol: Rank tolerance on singular values.

    Returns:
        ``(y, lam)``.
    """
    m = len(r)
    rn2 = 0.0
    for v in r:
        rn2 += v * v
    if m == 1:
        w = S[0][0]
        lam = dynamic_damping(math.sqrt(max(w, 0.0)), math.sqrt(rn2) / velocity_norm_max)
        if not w > rank_tol * rank_tol:
            return [0.0], lam
        return [r[0] / (w + lam * lam)], lam
    if m <= 3:
        sigma_min = math.sqrt(max(min_eigenvalue(S), 0.0))
        lam = dynamic_damping(sigma_min, math.sqrt(rn2) / velocity_norm_max)
        if sigma_min > rank_tol:
            y = _solve_small(S, lam * lam, r)
            if y is not None:
                return y, lam
    # Larger, or (near) singular: eigendecomposition with the rank tolerance (LAPACK dsyevd
    # directly: numpy.linalg.eigh costs several times more on such small matrices).
    w_arr, U, info = lapack.dsyevd(np.array(S))
    if info != 0:
        w_arr, U = np.linalg.eigh(np.array(S))
    sigma_min = math.sqrt(max(float(w_arr[0]), 0.0))
    lam = dynamic_damping(sigma_min, math.sqrt(rn2) / velocity_norm_max)
    keep = w_arr > rank_tol * rank_tol
    gains = np.zeros(m)
    gains[keep] = 1.0 / (w_arr[keep] + lam * lam)
    return (U @ (gains * (U.T @ np.array(r)))).tolist(), lam

r"""Damped least squares with the paper's dynamic damping (sec. II-A), in Gram coordinates.

The solver never inverts a Jacobian directly. Every velocity the cascade produces is a
combination of the task rows, :math:`\dot q = A^T z`, so each level only needs small symmetric
matrices built from the Gram matrix :math:`G = AA^T` of the stacked rows: for a level whose
(projected) Jacobian is :math:`B`, :math:`S = BB^T` (m × m, m ≤ 6 in practice) and

.. math::
    B^\# r = B^T (BB^T + \lambda^2 I_m)^{-1} r = B^T y,\qquad y = (S + \lambda^2 I_m)^{-1} r

whose eigenvalues are the squared singular values of ``B``. The functions are compiled with
numba (``cache=True``) and called from the compiled mode search of :mod:`tpik.cascade`; they
work on the leading ``m × m`` block of preallocated workspaces, so a control step allocates
nothing per level. They are plain functions of arrays and can be called from Python too.
"""

from __future__ import annotations

import math

import numba
import numpy as np

_TWO_PI_3 = 2.0 * math.pi / 3.0


@numba.njit(cache=True, nogil=True)
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


@numba.njit(cache=True, nogil=True)
def min_eigenvalue(S: np.ndarray, m: int) -> float:
    """Smallest eigenvalue of the symmetric block ``S[:m, :m]`` (closed form up to 3 × 3).

    Returns:
        The smallest eigenvalue (may be slightly negative for a singular PSD matrix).
    """
    if m == 1:
        return S[0, 0]
    if m == 2:
        a, b, c = S[0, 0], S[0, 1], S[1, 1]
        return 0.5 * (a + c) - math.sqrt(0.25 * (a - c) ** 2 + b * b)
    if m == 3:
        # Trigonometric solution of the characteristic cubic of a symmetric 3 × 3 matrix.
        a, b, c = S[0, 0], S[1, 1], S[2, 2]
        d, e, f = S[0, 1], S[0, 2], S[1, 2]
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
    return np.linalg.eigvalsh(np.ascontiguousarray(S[:m, :m]))[0]


@numba.njit(cache=True, nogil=True)
def jacobi_eigh(S: np.ndarray, m: int, A: np.ndarray, evals: np.ndarray, U: np.ndarray) -> None:
    r"""Eigenvalues (ascending) and eigenvectors (columns of ``U``) of the symmetric block ``S[:m, :m]``.

    Cyclic Jacobi rotations (Golub & Van Loan, Alg. 8.5.3) until the off-diagonal part is at
    round-off of the diagonal: for the small blocks of a cascade level (m ≤ ~12) it needs a few
    sweeps and no allocation, where LAPACK's ``eigh`` costs a call and its workspaces. Jacobi is
    at least as accurate (small eigenvalues to high relative accuracy); ``A`` is a workspace
    (≥ m × m), overwritten.
    """
    for i in range(m):
        for j in range(m):
            A[i, j] = S[i, j]
            U[i, j] = 1.0 if i == j else 0.0
    for _ in range(60):
        off = 0.0
        diag = 0.0
        for i in range(m):
            diag += A[i, i] * A[i, i]
            for j in range(i + 1, m):
                off += A[i, j] * A[i, j]
        if off <= 1e-34 * diag or off == 0.0:
            break
        for p in range(m - 1):
            for q in range(p + 1, m):
                apq = A[p, q]
                if apq == 0.0:
                    continue
                tau = (A[q, q] - A[p, p]) / (2.0 * apq)
                t = (1.0 if tau >= 0.0 else -1.0) / (abs(tau) + math.sqrt(1.0 + tau * tau))
                c = 1.0 / math.sqrt(1.0 + t * t)
                sn = t * c
                for k in range(m):  # A <- A J (columns p, q)
                    akp, akq = A[k, p], A[k, q]
                    A[k, p] = c * akp - sn * akq
                    A[k, q] = sn * akp + c * akq
                for k in range(m):  # A <- Jᵀ A (rows p, q)
                    apk, aqk = A[p, k], A[q, k]
                    A[p, k] = c * apk - sn * aqk
                    A[q, k] = sn * apk + c * aqk
                A[p, q] = 0.0
                A[q, p] = 0.0
                for k in range(m):  # U <- U J
                    ukp, ukq = U[k, p], U[k, q]
                    U[k, p] = c * ukp - sn * ukq
                    U[k, q] = sn * ukp + c * ukq
    for i in range(m):
        evals[i] = A[i, i]
    for i in range(1, m):  # insertion sort, columns of U along
        j = i
        while j > 0 and evals[j - 1] > evals[j]:
            evals[j - 1], evals[j] = evals[j], evals[j - 1]
            for k in range(m):
                U[k, j - 1], U[k, j] = U[k, j], U[k, j - 1]
            j -= 1


@numba.njit(cache=True, nogil=True)
def forward(L: np.ndarray, b: np.ndarray, m: int, w: np.ndarray) -> None:
    """Solve ``L w = b`` for the lower-triangular block ``L[:m, :m]`` (into ``w[:m]``)."""
    for j in range(m):
        acc = b[j]
        for k in range(j):
            acc -= L[j, k] * w[k]
        w[j] = acc / L[j, j]


@numba.njit(cache=True, nogil=True)
def backward(L: np.ndarray, w: np.ndarray, m: int, u: np.ndarray) -> None:
    """Solve ``Lᵀ u = w`` for the lower-triangular block ``L[:m, :m]`` (into ``u[:m]``)."""
    for j in range(m - 1, -1, -1):
        acc = w[j]
        for k in range(j + 1, m):
            acc -= L[k, j] * u[k]
        u[j] = acc / L[j, j]


@numba.njit(cache=True, nogil=True)
def cholesky_solve(S: np.ndarray, shift: float, r: np.ndarray, m: int, L: np.ndarray, y: np.ndarray) -> bool:
    r"""Solve :math:`(S + \text{shift}\,I) y = r` on the leading m × m block by Cholesky.

    Args:
        S: Symmetric matrix (leading block used).
        shift: Added to the diagonal (λ²).
        r: Right-hand side (first m entries).
        m: Size.
        L: Workspace for the factor, at least m × m.
        y: Output, at least m entries.

    Returns:
        False (``y`` undefined) if the shifted matrix is not positive definite.
    """
    for i in range(m):
        for j in range(i):
            acc = S[i, j]
            for k in range(j):
                acc -= L[i, k] * L[j, k]
            L[i, j] = acc / L[j, j]
        d = S[i, i] + shift
        for k in range(i):
            d -= L[i, k] * L[i, k]
        if not d > 0.0:
            return False
        L[i, i] = math.sqrt(d)
    forward(L, r, m, y)
    backward(L, y, m, y)  # in place: entry j is read before it is written
    return True


@numba.njit(cache=True, nogil=True)
def gram_dls_star(
    S: np.ndarray, r: np.ndarray, m: int, sigma_star: float, rank_tol: float, work: np.ndarray, y: np.ndarray
) -> float:
    r"""Damped least squares in Gram coordinates with a given σ*: :math:`y = (S + \lambda^2 I)^{-1} r`.

    ``S = BBᵀ`` (leading m × m block) for the matrix ``B`` the level inverts; the caller forms
    :math:`B^T y`. λ is :func:`dynamic_damping` of :math:`\sigma_{\min}(B) =
    \sqrt{\lambda_{\min}(S)}` and ``sigma_star``. Directions whose singular value is at or
    below ``rank_tol`` are dropped (their damped gain is zero), so a rank-deficient ``B`` with
    λ = 0 never divides by zero.

    Args:
        S: :math:`BB^T`; leading m × m block used.
        r: Level reference [task unit/s]; first m entries used.
        m: Number of rows of the level.
        sigma_star: σ* of the damping (sec. II-A), in the unit of the singular values.
        rank_tol: Rank tolerance on singular values.
        work: Workspace, at least m × m.
        y: Output, at least m entries.

    Returns:
        λ.
    """
    if m == 1:
        w = S[0, 0]
        lam = dynamic_damping(math.sqrt(max(w, 0.0)), sigma_star)
        y[0] = r[0] / (w + lam * lam) if w > rank_tol * rank_tol else 0.0
        return lam
    if m <= 3:
        sigma_min = math.sqrt(max(min_eigenvalue(S, m), 0.0))
        lam = dynamic_damping(sigma_min, sigma_star)
        if sigma_min > rank_tol and cholesky_solve(S, lam * lam, r, m, work, y):
            return lam
    # Larger, or (near) singular: eigendecomposition with the rank tolerance.
    evals = np.empty(m)
    U = np.empty((m, m))
    jacobi_eigh(S, m, work, evals, U)
    lam = dynamic_damping(math.sqrt(max(evals[0], 0.0)), sigma_star)
    tol2 = rank_tol * rank_tol
    for i in range(m):
        y[i] = 0.0
    for k in range(m):
        if evals[k] > tol2:
            proj = 0.0
            for i in range(m):
                proj += U[i, k] * r[i]
            proj /= evals[k] + lam * lam
            for i in range(m):
                y[i] += U[i, k] * proj
    return lam

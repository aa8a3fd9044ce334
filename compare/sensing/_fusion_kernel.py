"""Compiled search of the fusion (:mod:`compare.sensing.fusion`): hidden points no other camera sees free.

One call handles one control point and one *owner* camera: the half-lines hidden behind the
owner's obstacle pixels are walked outward from their closest approach to the control point,
and the first sample that no other camera sees free is the owner's candidate. The numpy-free
inner loop keeps the search to a few microseconds per candidate half-line.
"""

from __future__ import annotations

import numba
import numpy as np

from compare.sensing._kernels import surveillance_boxes

_BUCKETS = 64


@numba.njit(cache=True, nogil=True, inline="always")
def _free_in(x: float, y: float, z: float, intr: np.ndarray, tau: np.ndarray, m: int, depth: np.ndarray) -> bool:
    r"""Whether camera ``m`` sees its sensor-frame point (x, y, z) free (module ``fusion`` rule).

    Free iff in range, in view, and in front of its nearest pixel's raw return ``r`` by more than
    the allowance: :math:`z < r - \tau(r)`. A pixel without a return in range says nothing.
    """
    lo = intr[m, 6]
    hi = intr[m, 7]
    if z < lo or z > hi:  # nearer than the minimum range or beyond the maximum: unknown
        return False
    iu = int(np.floor(intr[m, 2] + intr[m, 0] * x / z + 0.5))
    iv = int(np.floor(intr[m, 3] + intr[m, 1] * y / z + 0.5))
    if iu < 0 or iv < 0 or iu >= int(intr[m, 4]) or iv >= int(intr[m, 5]):  # out of view: unknown
        return False
    r = depth[iv, iu]
    if not lo <= r <= hi:  # no return in range (dropout, NaN): unknown
        return False
    return z < r - _allowance(tau, m, r)


@numba.njit(cache=True, nogil=True, inline="always")
def _allowance(tau: np.ndarray, m: int, depth: float) -> float:
    """Camera ``m``'s free-space allowance τ(d) = tolerance + k σ0 (d if proportional else 1) [m]."""
    return tau[m, 0] + tau[m, 1] * (depth if tau[m, 2] > 0.0 else 1.0)


@numba.njit(cache=True, nogil=True, inline="always")
def _seen_free(
    x: float,
    y: float,
    z: float,
    rot: np.ndarray,
    trans: np.ndarray,
    intr: np.ndarray,
    tau: np.ndarray,
    others: tuple[np.ndarray, ...],
) -> bool:
    """Whether some other camera sees the owner-frame point (x, y, z) free (:func:`_free_in` on its raw frame)."""
    for m in range(len(others)):
        xm = rot[m, 0, 0] * x + rot[m, 0, 1] * y + rot[m, 0, 2] * z + trans[m, 0]
        ym = rot[m, 1, 0] * x + rot[m, 1, 1] * y + rot[m, 1, 2] * z + trans[m, 1]
        zm = rot[m, 2, 0] * x + rot[m, 2, 1] * y + rot[m, 2, 2] * z + trans[m, 2]
        if _free_in(xm, ym, zm, intr, tau, m, others[m]):
            return True
    return False


@numba.njit(cache=True, nogil=True)
def seen_free(
    point: np.ndarray,
    rot: np.ndarray,
    trans: np.ndarray,
    intr: np.ndarray,
    tau: np.ndarray,
    others: tuple[np.ndarray, ...],
) -> bool:
    """Whether some other camera sees the owner-frame point free (arguments as for :func:`occluded_search`)."""
    return _seen_free(point[0], point[1], point[2], rot, trans, intr, tau, others)


@numba.njit(cache=True, nogil=True)
def occluded_search(
    depth: np.ndarray,
    box: np.ndarray,
    xn: np.ndarray,
    yn: np.ndarray,
    inv_rr: np.ndarray,
    min_range: float,
    max_range: float,
    p: np.ndarray,
    radius_lo: float,
    radius_hi: float,
    step: float,
    budget: int,
    rot: np.ndarray,
    trans: np.ndarray,
    intr: np.ndarray,
    tau: np.ndarray,
    others: tuple[np.ndarray, ...],
    work: np.ndarray,
) -> tuple[float, float, float, float, int, bool]:
    """Closest point hidden behind the owner's obstacle pixels that no other camera sees free.

    Args:
        depth: The owner's filtered depth image [m], (H, W), float32 (0/NaN: no obstacle).
        box: The owner's surveillance box ``(v0, v1, u0, u1)`` of the control point.
        xn: ``(u - cx) / fx`` per column of the owner, (W,).
        yn: ``(v - cy) / fy`` per row, (H,).
        inv_rr: ``1 / (1 + xn² + yn²)`` per pixel, (H, W).
        min_range: Owner's smallest valid depth [m].
        max_range: Owner's largest valid depth [m].
        p: Control point in the owner's sensor frame [m], (3,).
        radius_lo: Every point nearer than this to ``p`` is known to be seen free by another
            camera [m] (the largest of the other cameras' :func:`not_free_bounds`).
        radius_hi: Only points nearer than this are of interest [m] (the best distance so far).
        step: Sampling step along a half-line, in depth [m].
        budget: Largest number of samples; beyond it the search ends conservatively.
        rot: Owner sensor frame → other camera's sensor frame, rotations (M, 3, 3).
        trans: ... translations (M, 3).
        intr: Other cameras' ``fx, fy, cx, cy, width, height, min_range, max_range``, (M, 8).
        tau: Other cameras' free-space allowance ``tolerance, k σ0, proportional`` (M, 3): a point
            is seen free in front of a return at depth r only if nearer than
            ``r − tolerance − k σ0 (r if proportional else 1)``.
        others: The other cameras' raw depth images, before the filters (float32, each its own
            shape; 0/NaN/out of range: no return, which sees nothing free).
        work: Scratch, float64 (6, H·W) of the owner.

    Returns:
        Distance [m] (``inf``: none nearer than ``radius_hi``), the point in the owner's sensor
        frame [m], the number of samples tested, and whether the budget ran out (then the
        distance is the nearest remaining half-line's unconstrained one: conservative).
    """
    n = _hidden_candidates(depth, box, xn, yn, inv_rr, min_range, max_range, p, radius_hi, work)
    best = np.inf
    bx = by = bz = 0.0
    if n == 0:
        return best, bx, by, bz, 0, False
    cand_a, cand_b, cand_d, cand_s0, cand_l2, cand_rr = work[0], work[1], work[2], work[3], work[4], work[5]
    counts, order = _nearest_first(cand_l2, n, radius_hi)
    limit = radius_hi
    lo2 = radius_lo * radius_lo
    samples = 0
    for j in range(_BUCKETS):
        if j * radius_hi / _BUCKETS >= min(best, limit):
            break
        for idx in range(counts[j], counts[j + 1]):
            i = order[idx]
            bound = min(best, limit)
            l2 = cand_l2[i]
            if l2 >= bound * bound:
                continue
            a, b, d, s0, rr = cand_a[i], cand_b[i], cand_d[i], cand_s0[i], cand_rr[i]
            half = np.sqrt((bound * bound - l2) / rr)  # |s − s0| within the current best distance
            inner = np.sqrt(max(lo2 - l2, 0.0) / rr)  # nearer than radius_lo: seen free for sure
            hit, off, s, samples, spent = _walk_half_line(
                a, b, d, s0, inner, half, step, samples, budget, rot, trans, intr, tau, others
            )
            if hit:
                best = np.sqrt(l2 + off * off * rr)
                bx, by, bz = a * s, b * s, s
            elif spent:
                best, bx, by, bz = _unclipped_rest(order, idx, n, work, best, bx, by, bz)
                return best, bx, by, bz, samples, True
    return best, bx, by, bz, samples, False


@numba.njit(cache=True, nogil=True, inline="always")
def _hidden_candidates(
    depth: np.ndarray,
    box: np.ndarray,
    xn: np.ndarray,
    yn: np.ndarray,
    inv_rr: np.ndarray,
    min_range: float,
    max_range: float,
    p: np.ndarray,
    radius_hi: float,
    work: np.ndarray,
) -> int:
    """The owner's half-lines hidden behind its surface nearer than ``radius_hi`` to ``p``; returns their number.

    Rows of ``work`` per candidate: a, b, d (its pixel's ray and depth), s0 (depth of the closest
    approach to ``p``), l² (squared distance of that approach) and |r|² = 1 / ``inv_rr``.
    """
    v0, v1, u0, u1 = box[0], box[1], box[2], box[3]
    px, py, pz = p[0], p[1], p[2]
    hi2 = radius_hi * radius_hi
    n = 0
    for v in range(v0, v1):
        for u in range(u0, u1):
            d = depth[v, u]
            if not (min_range <= d <= max_range):
                continue
            a = xn[u]
            b = yn[v]
            s0 = (a * px + b * py + pz) * inv_rr[v, u]
            if s0 <= d:  # the half-line's closest point is the measured surface point itself
                continue
            dx = a * s0 - px
            dy = b * s0 - py
            dz = s0 - pz
            l2 = dx * dx + dy * dy + dz * dz
            if l2 >= hi2:
                continue
            work[0, n] = a
            work[1, n] = b
            work[2, n] = d
            work[3, n] = s0
            work[4, n] = l2
            work[5, n] = 1.0 / inv_rr[v, u]
            n += 1
    return n


@numba.njit(cache=True, nogil=True, inline="always")
def _nearest_first(cand_l2: np.ndarray, n: int, radius_hi: float) -> tuple[np.ndarray, np.ndarray]:
    """Counting sort of the candidates on their line distance into ``_BUCKETS`` buckets of ``radius_hi``.

    Returns:
        Bucket starts (``_BUCKETS`` + 1, the last the total) and the candidates in bucket order.
    """
    counts = np.zeros(_BUCKETS + 1, dtype=np.int64)
    keys = np.empty(n, dtype=np.int64)
    for i in range(n):
        key = min(int(_BUCKETS * np.sqrt(cand_l2[i]) / radius_hi), _BUCKETS - 1)
        keys[i] = key
        counts[key + 1] += 1
    for j in range(_BUCKETS):
        counts[j + 1] += counts[j]
    order = np.empty(n, dtype=np.int64)
    fill = counts[:_BUCKETS].copy()
    for i in range(n):
        order[fill[keys[i]]] = i
        fill[keys[i]] += 1
    return counts, order


@numba.njit(cache=True, nogil=True, inline="always")
def _walk_half_line(
    a: float,
    b: float,
    d: float,
    s0: float,
    inner: float,
    half: float,
    step: float,
    samples: int,
    budget: int,
    rot: np.ndarray,
    trans: np.ndarray,
    intr: np.ndarray,
    tau: np.ndarray,
    others: tuple[np.ndarray, ...],
) -> tuple[bool, float, float, int, bool]:
    """Samples of one hidden half-line, outward from ``inner`` to ``half`` in depth from s0, both ways.

    Returns:
        (a sample no other camera sees free was found, its offset and depth s, the samples
        counted so far, the budget ran out before a hit).
    """
    k = 0
    while True:
        off = inner + k * step
        if off >= half:
            return False, 0.0, 0.0, samples, False
        for sign in (1.0, -1.0):
            if sign < 0.0 and off == 0.0:
                continue
            s = s0 + sign * off
            if s <= d:
                continue
            samples += 1
            if not _seen_free(a * s, b * s, s, rot, trans, intr, tau, others):
                return True, off, s, samples, False
        if samples >= budget:
            return False, 0.0, 0.0, samples, True
        k += 1


@numba.njit(cache=True, nogil=True, inline="always")
def _unclipped_rest(
    order: np.ndarray, start: int, n: int, work: np.ndarray, best: float, bx: float, by: float, bz: float
) -> tuple[float, float, float, float]:
    """Out of budget: every half-line not searched yet (from ``start`` in ``order``) counts unclipped."""
    for rest in range(start, n):
        r = order[rest]
        if work[4, r] < best * best:
            best = np.sqrt(work[4, r])
            bx, by, bz = work[0, r] * work[3, r], work[1, r] * work[3, r], work[3, r]
    return best, bx, by, bz


@numba.njit(cache=True, nogil=True)
def not_free_bounds(
    p: np.ndarray,
    raw: np.ndarray,
    todo: np.ndarray,
    xn: np.ndarray,
    yn: np.ndarray,
    inv_rr: np.ndarray,
    radius: np.ndarray,
    intr: np.ndarray,
    tau: np.ndarray,
) -> np.ndarray:
    r"""Per control point, a lower bound of its distance to the space one camera does not see free [m].

    That space (:func:`_free_in`) is what lies behind every pixel's raw return :math:`r` (from
    :math:`r - \tau(r)`, at nearest-pixel resolution: the person's, the arm's and the static
    scene's alike), the whole in-range ray of a pixel without a return, and what is out of view
    or range. With :math:`\delta` the distance from :math:`P` to the half-lines
    :math:`\{s\,\mathbf r_q : s \ge n_q\}` (:math:`n_q` the return, or the minimum range for
    none) of the pixels of the image box of the cube of half side ``radius`` around :math:`P`
    (every point within ``radius`` has its nearest pixel there), that space within ``radius`` of
    :math:`P` is at least :math:`\delta - 1.5\,\tau(z) - 0.8\,z / f_{min}` away (:math:`z` the
    farthest depth of interest), and at least as far as the view's border planes and range
    limits. When the camera does not see :math:`P` itself free (a control point inside its own
    link, behind the arm's surface) the bound is 0 without a scan.

    Args:
        p: Control points in the camera's sensor frame [m], (K, 3).
        raw: The camera's raw depth image [m], (H, W), float32 (0/NaN/out of range: no return).
        todo: Indices of the control points to bound, int64 (T,).
        xn: ``(u - cx) / fx`` per column, (W,).
        yn: ``(v - cy) / fy`` per row, (H,).
        inv_rr: ``1 / (1 + xn² + yn²)`` per pixel, (H, W).
        radius: Distance of interest per control point [m], at most ρ, (K,).
        intr: ``fx, fy, cx, cy, width, height, min_range, max_range`` of the camera, (1, 8).
        tau: ``tolerance, k σ0, proportional`` of the camera, (1, 3).

    Returns:
        The bounds [m] of the ``todo`` control points, (T,) (0 for a point out of view).
    """
    fx, fy, cx, cy, lo = intr[0, 0], intr[0, 1], intr[0, 2], intr[0, 3], intr[0, 6]
    width, height = int(intr[0, 4]), int(intr[0, 5])
    out = np.zeros(todo.size)
    for i in range(todo.size):
        k = todo[i]
        x, y, z = p[k, 0], p[k, 1], p[k, 2]
        bound = _view_bound(x, y, z, intr)
        if bound <= 0.0 or not _free_in(x, y, z, intr, tau, 0, raw):
            continue
        z_far = max(z + radius[k], 0.0)
        slack = 1.5 * _allowance(tau, 0, z_far) + 0.8 * z_far / min(fx, fy)
        box = surveillance_boxes(p[k : k + 1], radius[k], fx, fy, cx, cy, width, height, lo)[0]
        delta = _unseen_distance(raw, box, xn, yn, inv_rr, lo, intr[0, 7], x, y, z, slack)
        out[i] = max(min(bound, delta - slack), 0.0)
    return out


@numba.njit(cache=True, nogil=True, inline="always")
def _view_bound(x: float, y: float, z: float, intr: np.ndarray) -> float:
    """Distance from the sensor-frame point (x, y, z) to the camera's range limits and view border planes [m]."""
    fx, fy, cx, cy, width, height, lo, hi = (
        intr[0, 0], intr[0, 1], intr[0, 2], intr[0, 3], intr[0, 4], intr[0, 5], intr[0, 6], intr[0, 7],
    )  # fmt: skip
    bound = min(z - lo, hi - z)
    for lim, coord, f, c, sign in (
        (-0.5, x, fx, cx, 1.0),
        (width - 0.5, x, fx, cx, -1.0),
        (-0.5, y, fy, cy, 1.0),
        (height - 0.5, y, fy, cy, -1.0),
    ):
        alpha = (lim - c) / f  # the border plane: coord = alpha z
        bound = min(bound, sign * (coord - alpha * z) / np.sqrt(1.0 + alpha * alpha))
    return bound


@numba.njit(cache=True, nogil=True, inline="always")
def _unseen_distance(
    raw: np.ndarray,
    box: np.ndarray,
    xn: np.ndarray,
    yn: np.ndarray,
    inv_rr: np.ndarray,
    lo: float,
    hi: float,
    px: float,
    py: float,
    pz: float,
    stop: float,
) -> float:
    """Distance from P to the box's unseen half-lines ``{s r_q : s ≥ n_q}`` [m]; returns early once ≤ ``stop``.

    ``n_q`` is the pixel's raw return, or ``lo`` without a return in [lo, hi] (its whole ray is unknown).
    """
    best2 = np.inf
    stop2 = stop * stop if stop > 0.0 else 0.0
    for v in range(box[0], box[1]):
        b = yn[v]
        for u in range(box[2], box[3]):
            n = np.float64(raw[v, u])
            if not lo <= n <= hi:
                n = lo
            a = xn[u]
            s = max((a * px + b * py + pz) * inv_rr[v, u], n)
            dx = a * s - px
            dy = b * s - py
            dz = s - pz
            l2 = dx * dx + dy * dy + dz * dz
            if l2 < best2:
                best2 = l2
                if best2 <= stop2:
                    return np.sqrt(best2)
    return np.sqrt(best2)

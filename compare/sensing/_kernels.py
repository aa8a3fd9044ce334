"""Compiled inner loops of the depth-space distance (numba), same arithmetic as the numpy path.

One scan of the union of the control points' surveillance boxes collects the valid pixels;
each control point then evaluates only the collected pixels inside its own box, with no
temporaries. Several times faster than the vectorised numpy version
(``compare.bench.sensing``); the numpy version in :mod:`compare.sensing.depth_distance`
stays the reference and the tests check that both agree.
"""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True, nogil=True)
def closest_in_boxes(
    depth: np.ndarray,
    boxes: np.ndarray,
    xn: np.ndarray,
    yn: np.ndarray,
    inv_rr: np.ndarray,
    points: np.ndarray,
    support: int,
    min_range: float,
    max_range: float,
    work_v: np.ndarray,
    work_u: np.ndarray,
    work_d: np.ndarray,
    measured: bool = False,
) -> tuple[
    np.ndarray,
    np.ndarray,
    np.ndarray,
    np.ndarray,
    np.ndarray,
    np.ndarray,
    np.ndarray,
    np.ndarray,
    np.ndarray,
    np.ndarray,
]:
    """Per control point, the ``support``-th smallest squared distance to the pixels' occluded half-lines.

    Args:
        depth: Depth image [m], (H, W); pixels outside [min_range, max_range] (0, NaN, inf) are skipped.
        boxes: Half-open pixel boxes ``(v0, v1, u0, u1)`` per control point, int64 (K, 4); an
            empty box (v0 >= v1) disables its control point.
        xn: ``(u - cx) / fx`` per column, (W,).
        yn: ``(v - cy) / fy`` per row, (H,).
        inv_rr: ``1 / (1 + xn[u]² + yn[v]²)`` per pixel, (H, W).
        points: Control points in the sensor frame [m], (K, 3).
        support: Rank k of the reported distance (1 = minimum).
        min_range: Smallest valid depth [m].
        max_range: Largest valid depth [m].
        work_v: Scratch, int32 (H·W,).
        work_u: Scratch, int32 (H·W,).
        work_d: Scratch, float64 (H·W,).
        measured: Also find the closest *measured* point: the surface point ``(a d, b d, d)`` of
            the nearest pixel that has a neighbour within ``SUPPORT_DEPTH_M`` in depth (a flying
            pixel is not a measurement; its hidden half-line still counts).

    Returns:
        Per control point (arrays of length K): squared distance [m²] (``inf`` when fewer than
        ``support`` pixels), ``a``, ``b``, ``s`` of the chosen pixel (its point is
        ``(a s, b s, s)``), whether that point lies behind the measured surface (``s > d``:
        assumed from hidden space, not measured), the number of valid pixels in its box, and
        (``measured``; else ``inf`` and zeros) the squared distance and ``a``, ``b``, ``d`` of
        the closest measured point.
    """
    k_points = boxes.shape[0]
    n = _collect_valid_pixels(depth, boxes, min_range, max_range, work_v, work_u, work_d)
    out_d2 = np.full(k_points, np.inf)
    out_a = np.zeros(k_points)
    out_b = np.zeros(k_points)
    out_s = np.zeros(k_points)
    out_hidden = np.zeros(k_points, dtype=np.bool_)
    count = np.zeros(k_points, dtype=np.int64)
    out_e2 = np.full(k_points, np.inf)
    out_ea = np.zeros(k_points)
    out_eb = np.zeros(k_points)
    out_ed = np.zeros(k_points)
    best = np.empty((5, support))  # rows: d², a, b, s, d of the ``support`` nearest so far
    for k in range(k_points):
        v0, v1, u0, u1 = boxes[k, 0], boxes[k, 1], boxes[k, 2], boxes[k, 3]
        px, py, pz = points[k, 0], points[k, 1], points[k, 2]
        if support == 1:  # plain minimum in registers: the common case, ~3x faster
            m, ma, mb, ms, md, c, e, ea, eb, ed, ei = _nearest_in_box(
                work_v, work_u, work_d, n, v0, v1, u0, u1, xn, yn, inv_rr, px, py, pz, measured
            )
        else:
            m, ma, mb, ms, md, c, e, ea, eb, ed, ei = _kth_nearest_in_box(
                work_v, work_u, work_d, n, v0, v1, u0, u1, xn, yn, inv_rr, px, py, pz, measured, best
            )
        if measured and ei >= 0 and not _supported(depth, work_v[ei], work_u[ei], work_d[ei], min_range, max_range):
            e, ea, eb, ed = _closest_supported(
                depth, work_v, work_u, work_d, n, v0, v1, u0, u1, xn, yn, px, py, pz, min_range, max_range
            )
        count[k] = c
        out_d2[k], out_a[k], out_b[k], out_s[k], out_hidden[k] = m, ma, mb, ms, ms > md
        out_e2[k], out_ea[k], out_eb[k], out_ed[k] = e, ea, eb, ed
    return out_d2, out_a, out_b, out_s, out_hidden, count, out_e2, out_ea, out_eb, out_ed


@numba.njit(cache=True, nogil=True, inline="always")
def _collect_valid_pixels(
    depth: np.ndarray,
    boxes: np.ndarray,
    min_range: float,
    max_range: float,
    work_v: np.ndarray,
    work_u: np.ndarray,
    work_d: np.ndarray,
) -> int:
    """Row, column and depth of every valid pixel of the union of the non-empty boxes; returns their number."""
    v_lo, v_hi, u_lo, u_hi = depth.shape[0], 0, depth.shape[1], 0
    for k in range(boxes.shape[0]):
        if boxes[k, 0] < boxes[k, 1] and boxes[k, 2] < boxes[k, 3]:
            v_lo = min(v_lo, boxes[k, 0])
            v_hi = max(v_hi, boxes[k, 1])
            u_lo = min(u_lo, boxes[k, 2])
            u_hi = max(u_hi, boxes[k, 3])
    n = 0
    for v in range(v_lo, v_hi):
        for u in range(u_lo, u_hi):
            d = depth[v, u]
            if min_range <= d <= max_range:  # False for NaN
                work_v[n] = v
                work_u[n] = u
                work_d[n] = d
                n += 1
    return n


@numba.njit(cache=True, nogil=True, inline="always")
def _nearest_in_box(
    work_v: np.ndarray,
    work_u: np.ndarray,
    work_d: np.ndarray,
    n: int,
    v0: int,
    v1: int,
    u0: int,
    u1: int,
    xn: np.ndarray,
    yn: np.ndarray,
    inv_rr: np.ndarray,
    px: float,
    py: float,
    pz: float,
    measured: bool,
) -> tuple[float, float, float, float, float, int, float, float, float, float, int]:
    """Support 1 of :func:`closest_in_boxes` for one box: the nearest half-line and measured point.

    Returns:
        d², a, b, s, d of the nearest half-line's point, the pixels in the box, and d², a, b, d
        and the collected index of the nearest surface point (index −1: none or not ``measured``).
    """
    e, ea, eb, ed, ei = np.inf, 0.0, 0.0, 0.0, -1
    m, ma, mb, ms, md, c = np.inf, 0.0, 0.0, 0.0, 0.0, 0
    for i in range(n):
        v = work_v[i]
        u = work_u[i]
        if v < v0 or v >= v1 or u < u0 or u >= u1:
            continue
        c += 1
        a = xn[u]
        b = yn[v]
        d = work_d[i]
        ir = inv_rr[v, u]
        s0 = (a * px + b * py + pz) * ir
        s = max(s0, d)
        dx = a * s - px
        dy = b * s - py
        dz = s - pz
        d2 = dx * dx + dy * dy + dz * dz
        if d2 < m:
            m, ma, mb, ms, md = d2, a, b, s, d
        if measured:
            # Surface point: the same point when s = d, else |r|² (s0 − d)² farther (squared).
            e2 = d2 if s0 <= d else d2 + (s0 - d) * (s0 - d) / ir
            if e2 < e:
                e, ea, eb, ed, ei = e2, a, b, d, i
    return m, ma, mb, ms, md, c, e, ea, eb, ed, ei


@numba.njit(cache=True, nogil=True, inline="always")
def _kth_nearest_in_box(
    work_v: np.ndarray,
    work_u: np.ndarray,
    work_d: np.ndarray,
    n: int,
    v0: int,
    v1: int,
    u0: int,
    u1: int,
    xn: np.ndarray,
    yn: np.ndarray,
    inv_rr: np.ndarray,
    px: float,
    py: float,
    pz: float,
    measured: bool,
    best: np.ndarray,
) -> tuple[float, float, float, float, float, int, float, float, float, float, int]:
    """Support k > 1 of :func:`closest_in_boxes` for one box (same returns as :func:`_nearest_in_box`).

    ``best`` (5, k) is scratch: the k nearest half-line points so far, sorted (insertion).
    """
    last = best.shape[1] - 1
    best[0, :] = np.inf
    best[3, :] = 0.0
    best[4, :] = 0.0
    e, ea, eb, ed, ei = np.inf, 0.0, 0.0, 0.0, -1
    c = 0
    for i in range(n):
        v = work_v[i]
        u = work_u[i]
        if v < v0 or v >= v1 or u < u0 or u >= u1:
            continue
        c += 1
        a = xn[u]
        b = yn[v]
        d = work_d[i]
        # Depth of the ray's closest approach to P, never in front of the measured surface.
        s = max((a * px + b * py + pz) * inv_rr[v, u], d)
        dx = a * s - px
        dy = b * s - py
        dz = s - pz
        d2 = dx * dx + dy * dy + dz * dz
        if d2 < best[0, last]:
            j = last
            while j > 0 and best[0, j - 1] > d2:
                best[0, j] = best[0, j - 1]
                best[1, j] = best[1, j - 1]
                best[2, j] = best[2, j - 1]
                best[3, j] = best[3, j - 1]
                best[4, j] = best[4, j - 1]
                j -= 1
            best[0, j] = d2
            best[1, j] = a
            best[2, j] = b
            best[3, j] = s
            best[4, j] = d
        if measured:
            dx = a * d - px
            dy = b * d - py
            dz = d - pz
            d2 = dx * dx + dy * dy + dz * dz
            if d2 < e:
                e, ea, eb, ed, ei = d2, a, b, d, i
    return best[0, last], best[1, last], best[2, last], best[3, last], best[4, last], c, e, ea, eb, ed, ei


SUPPORT_DEPTH_M = 0.05
"""A measured point needs a neighbouring pixel whose depth is within this [m] (:func:`_supported`)."""


@numba.njit(cache=True, nogil=True, inline="always")
def _supported(depth: np.ndarray, v: int, u: int, d: float, min_range: float, max_range: float) -> bool:
    """Whether one of the 8 neighbours of pixel (v, u) is valid and within ``SUPPORT_DEPTH_M`` of its depth ``d``.

    A lone pixel far from all its neighbours in depth is a flying pixel (a real sensor's at depth
    edges; the rasteriser's at faces seen edge-on), not a surface: it does not count as measured.
    """
    height, width = depth.shape
    for dv in (-1, 0, 1):
        for du in (-1, 0, 1):
            if dv == 0 and du == 0:
                continue
            vv, uu = v + dv, u + du
            if 0 <= vv < height and 0 <= uu < width:
                f = depth[vv, uu]
                if min_range <= f <= max_range and abs(f - d) <= SUPPORT_DEPTH_M:
                    return True
    return False


@numba.njit(cache=True, nogil=True)
def _closest_supported(
    depth: np.ndarray,
    work_v: np.ndarray,
    work_u: np.ndarray,
    work_d: np.ndarray,
    n: int,
    v0: int,
    v1: int,
    u0: int,
    u1: int,
    xn: np.ndarray,
    yn: np.ndarray,
    px: float,
    py: float,
    pz: float,
    min_range: float,
    max_range: float,
) -> tuple[float, float, float, float]:
    """The closest measured point among the supported pixels of a box (the rare second pass)."""
    e, ea, eb, ed = np.inf, 0.0, 0.0, 0.0
    for i in range(n):
        v = work_v[i]
        u = work_u[i]
        if v < v0 or v >= v1 or u < u0 or u >= u1:
            continue
        a = xn[u]
        b = yn[v]
        d = work_d[i]
        dx = a * d - px
        dy = b * d - py
        dz = d - pz
        d2 = dx * dx + dy * dy + dz * dz
        if d2 < e and _supported(depth, v, u, d, min_range, max_range):
            e, ea, eb, ed = d2, a, b, d
    return e, ea, eb, ed


@numba.njit(cache=True, nogil=True)
def surveillance_boxes(
    points: np.ndarray,
    rho: float,
    fx: float,
    fy: float,
    cx: float,
    cy: float,
    width: int,
    height: int,
    min_range: float,
) -> np.ndarray:
    """Pixel boxes ``(v0, v1, u0, u1)`` (half-open) of the cubes of half side ``rho`` around ``points``.

    The box of the projections of the cube's eight corners (exact for a convex polytope in
    front of the camera), with the cube's depth cut at ``min_range``: nothing nearer can be
    measured. Points not finite or cubes entirely nearer than ``min_range`` or out of the image
    get an empty box (all zeros). Shape (K, 4), int64.
    """
    k_points = points.shape[0]
    boxes = np.zeros((k_points, 4), dtype=np.int64)
    for k in range(k_points):
        px, py, pz = points[k, 0], points[k, 1], points[k, 2]
        if not (np.isfinite(px) and np.isfinite(py) and np.isfinite(pz)):
            continue
        z_far = pz + rho
        if z_far < min_range:
            continue
        z_near = max(pz - rho, min_range)
        u_min, u_max, v_min, v_max = np.inf, -np.inf, np.inf, -np.inf
        for z in (z_near, z_far):
            for x in (px - rho, px + rho):
                u = cx + fx * x / z
                u_min = min(u_min, u)
                u_max = max(u_max, u)
            for y in (py - rho, py + rho):
                v = cy + fy * y / z
                v_min = min(v_min, v)
                v_max = max(v_max, v)
        u0 = max(int(np.floor(u_min)), 0)
        u1 = min(int(np.ceil(u_max)) + 1, width)
        v0 = max(int(np.floor(v_min)), 0)
        v1 = min(int(np.ceil(v_max)) + 1, height)
        if u0 < u1 and v0 < v1:
            boxes[k, 0], boxes[k, 1], boxes[k, 2], boxes[k, 3] = v0, v1, u0, u1
    return boxes


@numba.njit(cache=True, nogil=True)
def closest_on_capsules_kernel(
    points: np.ndarray, a: np.ndarray, b: np.ndarray, radius: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Compiled :func:`compare.sensing.geometric_distance.closest_on_capsules` (same arithmetic).

    Args:
        points: Query points [m], (K, 3).
        a: Capsule segment starts [m], (G, 3).
        b: Capsule segment ends [m], (G, 3).
        radius: Radii [m], (G,).

    Returns:
        Distances [m] (K,), 0 inside a capsule, and closest surface points [m] (K, 3).
    """
    n_points = points.shape[0]
    n_geoms = a.shape[0]
    dist = np.empty(n_points)
    closest = np.empty((n_points, 3))
    for k in range(n_points):
        best = np.inf
        bc0 = bc1 = bc2 = 0.0
        bp0 = bp1 = bp2 = 0.0
        bn = 1.0
        br = 0.0
        for g in range(n_geoms):
            ab0, ab1, ab2 = b[g, 0] - a[g, 0], b[g, 1] - a[g, 1], b[g, 2] - a[g, 2]
            ap0, ap1, ap2 = points[k, 0] - a[g, 0], points[k, 1] - a[g, 1], points[k, 2] - a[g, 2]
            len2 = ab0 * ab0 + ab1 * ab1 + ab2 * ab2
            t = (ap0 * ab0 + ap1 * ab1 + ap2 * ab2) / len2 if len2 > 0.0 else 0.0
            t = min(max(t, 0.0), 1.0)
            c0, c1, c2 = a[g, 0] + t * ab0, a[g, 1] + t * ab1, a[g, 2] + t * ab2
            p0, p1, p2 = points[k, 0] - c0, points[k, 1] - c1, points[k, 2] - c2
            n = np.sqrt(p0 * p0 + p1 * p1 + p2 * p2)
            surface = n - radius[g]
            if surface < best:
                best = surface
                bc0, bc1, bc2 = c0, c1, c2
                bp0, bp1, bp2 = p0, p1, p2
                bn = n
                br = radius[g]
        if best > 0.0:
            scale = br / max(bn, 1e-12)
            closest[k, 0] = bc0 + scale * bp0
            closest[k, 1] = bc1 + scale * bp1
            closest[k, 2] = bc2 + scale * bp2
            dist[k] = best
        else:
            closest[k, 0], closest[k, 1], closest[k, 2] = points[k, 0], points[k, 1], points[k, 2]
            dist[k] = 0.0
    return dist, closest


@numba.njit(cache=True, nogil=True)
def closest_on_geoms_kernel(
    points: np.ndarray,
    geom_xpos: np.ndarray,
    geom_xmat: np.ndarray,
    geom_ids: np.ndarray,
    half_length: np.ndarray,
    radius: np.ndarray,
    a: np.ndarray,
    b: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    r""":func:`closest_on_capsules_kernel` on the capsules of MuJoCo geoms, their segments formed here.

    Segment of geom g: :math:`A, B = c \mp h\,z` with its centre c (``geom_xpos``), the local z
    axis z (column 2 of its row-major ``geom_xmat``) and its half length h (0 for a sphere): the
    arithmetic of :meth:`compare.sensing.geometric_distance.GeometricDistance.segments`.

    Args:
        points: Query points [m], (K, 3).
        geom_xpos: ``MjData.geom_xpos`` [m], (ngeom, 3).
        geom_xmat: ``MjData.geom_xmat``, (ngeom, 9).
        geom_ids: The obstacle geoms, int64 (G,).
        half_length: Half length of each obstacle geom's segment [m], (G,).
        radius: Radii [m], (G,).
        a: Scratch for the segment starts, (G, 3).
        b: Scratch for the segment ends, (G, 3).

    Returns:
        As :func:`closest_on_capsules_kernel`.
    """
    for g in range(geom_ids.shape[0]):
        i = geom_ids[g]
        for c in range(3):
            offset = geom_xmat[i, 2 + 3 * c] * half_length[g]
            a[g, c] = geom_xpos[i, c] - offset
            b[g, c] = geom_xpos[i, c] + offset
    return closest_on_capsules_kernel(points, a, b, radius)

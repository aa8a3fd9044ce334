"""Compiled per-pixel passes of a depth frame (numba): buffer to metres, valid count, background, arm.

Each kernel is one pass over the pixels with the float32 arithmetic of the vectorised numpy
expressions it replaces, operation for operation (no fused multiply-add, no reassociation), so
the frames are the same bit for bit; tests/compare/sensing/test_frame_kernels.py checks them
against those numpy expressions.
"""

from __future__ import annotations

import mujoco
import numba
import numpy as np

SPHERE, CAPSULE, CYLINDER, BOX = (
    int(g)
    for g in (
        mujoco.mjtGeom.mjGEOM_SPHERE,
        mujoco.mjtGeom.mjGEOM_CAPSULE,
        mujoco.mjtGeom.mjGEOM_CYLINDER,
        mujoco.mjtGeom.mjGEOM_BOX,
    )
)
"""Geom types with an exact signed distance (others: their bounding sphere), as plain ints for numba."""


@numba.njit(cache=True, nogil=True)
def depth_from_buffer(
    raw: np.ndarray,
    f_minus_n: np.float32,
    near: np.float32,
    fn: np.float32,
    normal: np.ndarray,
    std: np.float32,
    proportional: bool,
    dropped: np.ndarray,
    min_range: np.float32,
    max_range: np.float32,
    out: np.ndarray,
) -> None:
    """Metric depth [m] of an OpenGL depth buffer (rows bottom-up) into ``out``, noise and range applied.

    ``d = f n / ((f - n) z + n)``; then ``d += σ₀ ε`` (``σ₀ ε d`` when proportional) where
    ``normal`` (standard normals ε) has pixels, 0 where ``dropped`` has pixels and is True, and 0
    outside [min_range, max_range]. Empty ``normal`` / ``dropped``: no noise / no dropout.
    """
    height, width = out.shape
    noisy = normal.size > 0
    dropout = dropped.size > 0
    for v in range(height):
        row = raw[height - 1 - v]
        for u in range(width):
            d = fn / (row[u] * f_minus_n + near)
            if noisy:
                e = normal[v, u] * std
                if proportional:
                    e = e * d
                d = d + e
            if dropout and dropped[v, u]:
                d = np.float32(0.0)
            if d < min_range or d > max_range:
                d = np.float32(0.0)
            out[v, u] = d


@numba.njit(cache=True, nogil=True)
def zero_at_or_beyond(depth: np.ndarray, threshold: np.ndarray, out: np.ndarray) -> None:
    """``out = depth`` with 0 where ``depth >= threshold`` (NaN pixels stay NaN); ``out`` may be ``depth``."""
    height, width = depth.shape
    for v in range(height):
        for u in range(width):
            d = depth[v, u]
            out[v, u] = np.float32(0.0) if d >= threshold[v, u] else d


@numba.njit(cache=True, nogil=True)
def count_in_range(depth: np.ndarray, lo: np.float32, hi: np.float32) -> int:
    """Number of pixels with ``lo <= depth <= hi`` (NaN never counts)."""
    height, width = depth.shape
    n = 0
    for v in range(height):
        for u in range(width):
            d = depth[v, u]
            if d >= lo and d <= hi:
                n += 1
    return n


@numba.njit(inline="always")
def _maximum(a: np.float32, b: np.float32) -> np.float32:
    """``np.maximum``: NaN if either is NaN."""
    if a != a or b != b:
        return a + b
    return a if a >= b else b


@numba.njit(inline="always")
def _minimum(a: np.float32, b: np.float32) -> np.float32:
    """``np.minimum``: NaN if either is NaN."""
    if a != a or b != b:
        return a + b
    return a if a <= b else b


@numba.njit(inline="always")
def _signed_distance(kind: int, s0: np.float32, s1: np.float32, s2: np.float32, x, y, z):  # noqa: ANN001, ANN202
    """Signed distance [m] of a point in the geom's frame to a sphere, capsule, cylinder or box."""
    zero = np.float32(0.0)
    if kind == SPHERE:
        return np.sqrt(x * x + y * y + z * z) - s0
    if kind == CAPSULE:
        zc = z - _minimum(_maximum(z, -s1), s1)
        return np.sqrt(x * x + y * y + zc * zc) - s0
    if kind == CYLINDER:
        radial = np.sqrt(x * x + y * y) - s0
        axial = np.abs(z) - s1
        out_r = _maximum(radial, zero)
        out_a = _maximum(axial, zero)
        return np.sqrt(out_r * out_r + out_a * out_a) + _minimum(_maximum(radial, axial), zero)
    qx = np.abs(x) - s0
    qy = np.abs(y) - s1
    qz = np.abs(z) - s2
    ox, oy, oz = _maximum(qx, zero), _maximum(qy, zero), _maximum(qz, zero)
    inside = _minimum(_maximum(_maximum(qx, qy), qz), zero)
    return np.sqrt(ox * ox + oy * oy + oz * oz) + inside


@numba.njit(cache=True, nogil=True)
def remove_near_geoms(
    depth: np.ndarray,
    boxes: np.ndarray,
    centres: np.ndarray,
    rots: np.ndarray,
    kinds: np.ndarray,
    sizes: np.ndarray,
    radii: np.ndarray,
    exact: np.ndarray,
    xn: np.ndarray,
    yn: np.ndarray,
    margin: np.float32,
    allowance: np.float32,
    std: np.float32,
    proportional: bool,
) -> int:
    """Zero, geom after geom, the pixels whose point is within ``margin + allowance σ(d)`` of the geom.

    Geom ``i`` (centre ``centres[i]`` and axes ``rots[i]`` in the sensor frame, float32) is tested
    on the pixel box ``boxes[i] = (v0, v1, u0, u1)`` only (``v0 < 0``: not in view); a geom not
    ``exact`` is tested as the sphere of radius ``radii[i]``. σ(d) = σ₀ d when proportional, else
    σ₀ + 0 d (NaN at infinite depth, as numpy). Returns the number of pixels zeroed.
    """
    zero = np.float32(0.0)
    removed = 0
    for i in range(boxes.shape[0]):
        v0, v1, u0, u1 = boxes[i, 0], boxes[i, 1], boxes[i, 2], boxes[i, 3]
        if v0 < 0:
            continue
        c0, c1, c2 = centres[i, 0], centres[i, 1], centres[i, 2]
        r = rots[i]
        kind = kinds[i]
        s0, s1, s2 = sizes[i, 0], sizes[i, 1], sizes[i, 2]
        for v in range(v0, v1):
            yv = yn[v]
            for u in range(u0, u1):
                d = depth[v, u]
                if not d > zero:  # no return (0 or NaN): never removed
                    continue
                x = xn[u] * d - c0
                y = yv * d - c1
                z = d - c2
                lx = x * r[0, 0] + y * r[1, 0] + z * r[2, 0]
                ly = x * r[0, 1] + y * r[1, 1] + z * r[2, 1]
                lz = x * r[0, 2] + y * r[1, 2] + z * r[2, 2]
                if exact[i]:
                    sd = _signed_distance(kind, s0, s1, s2, lx, ly, lz)
                else:
                    sd = np.sqrt(lx * lx + ly * ly + lz * lz) - radii[i]
                if proportional:
                    sigma = std * d
                else:
                    sigma = std + zero * d
                if sd <= margin + allowance * sigma:
                    depth[v, u] = zero
                    removed += 1
    return removed

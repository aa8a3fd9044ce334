r"""Primitive stand-ins of mesh geoms, for the depth camera and the self-filter.

The work cell's self-filter (``compare.sensing.self_filter``) removes depth pixels within a
margin of the arm's geoms by exact signed distances to spheres, capsules, cylinders and boxes; a
mesh it could only treat as its bounding sphere (tens of cm too large on a 30 cm link). A robot
whose description has mesh collision geometry (a URDF from ``example-robot-data``) therefore gets,
per mesh, the smaller enclosing primitive of

* the box aligned with the mesh frame (MuJoCo puts a mesh's frame on its principal axes of
  inertia), of half sizes half the vertex extents, centred on them;
* the capsule along one of those axes (each tried) whose radius is the largest vertex distance
  from the axis line through the centre of the vertices' cross-section extents, with the
  shortest segment that still covers every vertex:

.. math:: t_- = \min_v\, (t_v + \sqrt{r^2 - d_v^2}),\qquad t_+ = \max_v\, (t_v - \sqrt{r^2 - d_v^2})

(:math:`t_v` the vertex's coordinate along the axis, :math:`d_v` its distance from it; the
segment is :math:`[t_-, t_+]`, a sphere when :math:`t_- > t_+`). Every vertex of the mesh is
inside its proxy, hence (the proxy being convex) the mesh's convex hull too: the arm the camera
sees is the proxies, and no pixel of it escapes the filter.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numpy as np


@dataclass(frozen=True)
class Proxy:
    """A primitive enclosing one mesh geom, in the mesh geom's frame.

    Attributes:
        kind: ``mujoco.mjtGeom.mjGEOM_BOX`` or ``mjGEOM_CAPSULE``.
        size: MuJoCo ``size`` (box: half sizes; capsule: radius, half length, 0) [m].
        pos: Centre in the mesh geom's frame [m]. Shape (3,).
        quat: Orientation (w, x, y, z) in the mesh geom's frame (capsule axis = its local z).
        volume_m3: Volume [m³].
    """

    kind: int
    size: np.ndarray
    pos: np.ndarray
    quat: np.ndarray
    volume_m3: float


# Rotations taking local z to the mesh frame's x, y, z axes (w, x, y, z).
_Z_TO_AXIS = (
    np.array([math.sqrt(0.5), 0.0, math.sqrt(0.5), 0.0]),
    np.array([math.sqrt(0.5), -math.sqrt(0.5), 0.0, 0.0]),
    np.array([1.0, 0.0, 0.0, 0.0]),
)


def enclosing_box(vertices: np.ndarray) -> Proxy:
    """Axis-aligned box (mesh frame) around ``vertices`` (n, 3) [m]."""
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    half = np.maximum((hi - lo) / 2.0, 1e-6)
    return Proxy(mujoco.mjtGeom.mjGEOM_BOX, half, (hi + lo) / 2.0, np.array([1.0, 0, 0, 0]), float(8 * np.prod(half)))


def enclosing_capsule(vertices: np.ndarray, axis: int) -> Proxy:
    """Capsule along mesh-frame axis ``axis`` (0, 1, 2) around ``vertices`` (module docstring)."""
    others = [k for k in range(3) if k != axis]
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    centre = (hi + lo) / 2.0
    rel = vertices - centre
    t = rel[:, axis]
    d = np.hypot(rel[:, others[0]], rel[:, others[1]])
    r = max(float(d.max()), 1e-6)
    reach = np.sqrt(np.maximum(r * r - d * d, 0.0))
    t_lo, t_hi = float(np.min(t + reach)), float(np.max(t - reach))
    if t_lo > t_hi:  # every vertex fits in one sphere of radius r
        t_lo = t_hi = 0.5 * (t_lo + t_hi)
    half_length = 0.5 * (t_hi - t_lo)
    pos = centre.copy()
    pos[axis] += 0.5 * (t_hi + t_lo)
    volume = math.pi * r * r * (2.0 * half_length) + 4.0 / 3.0 * math.pi * r**3
    size = np.array([r, max(half_length, 1e-9), 0.0])
    return Proxy(mujoco.mjtGeom.mjGEOM_CAPSULE, size, pos, _Z_TO_AXIS[axis].copy(), volume)


def fit_proxy(vertices: np.ndarray) -> Proxy:
    """The smallest of the box and the three axis capsules enclosing ``vertices`` (n, 3) [m]."""
    v = np.asarray(vertices, dtype=float)
    candidates = [enclosing_box(v)] + [enclosing_capsule(v, k) for k in range(3)]
    return min(candidates, key=lambda p: p.volume_m3)


def mesh_vertices(model: mujoco.MjModel, geom: int) -> np.ndarray:
    """Vertices of mesh geom ``geom`` in the geom's frame [m]. Shape (n, 3)."""
    mesh = int(model.geom_dataid[geom])
    start, count = int(model.mesh_vertadr[mesh]), int(model.mesh_vertnum[mesh])
    return np.array(model.mesh_vert[start : start + count], dtype=float)


def proxy_in_body(model: mujoco.MjModel, geom: int, proxy: Proxy) -> tuple[np.ndarray, np.ndarray]:
    """Position [m] and quaternion (w, x, y, z) of ``proxy`` in the body frame of mesh geom ``geom``."""
    rot = np.zeros(9)
    mujoco.mju_quat2Mat(rot, model.geom_quat[geom])
    pos = model.geom_pos[geom] + rot.reshape(3, 3) @ proxy.pos
    quat = np.zeros(4)
    mujoco.mju_mulQuat(quat, model.geom_quat[geom], proxy.quat)
    return pos, quat

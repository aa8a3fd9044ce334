r"""Obstacle distance from the MuJoCo geometry: control points against the person's capsules.

No rendering: each obstacle geom (capsule or sphere, read from ``MjData``) is a segment
:math:`[A, B]` with radius :math:`r`, and for a control point :math:`P`

.. math::
    C = A + \operatorname{clamp}\!\left(\frac{(P - A)\cdot(B - A)}{\|B - A\|^2}, 0, 1\right)(B - A),
    \qquad d = \max(\|P - C\| - r,\ 0),\qquad O = C + r\,\frac{P - C}{\|P - C\|}

(:math:`O = P` when :math:`P` is inside the capsule). All control points against all geoms
in one vectorised evaluation (~30 µs): the fast sensing mode of sweeps and the ground truth of
the depth-space tests.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import mujoco
import numpy as np

from compare.sensing._kernels import closest_on_geoms_kernel
from compare.sensing.exceptions import SensingError
from compare.sensing.renderer import PERSON_GROUP
from compare.sensing.results import DistanceResult, ObstacleReading


class GeometricDistance:
    """Exact distance from control points to the obstacle geoms of a scene.

    Args:
        model: Scene model.
        geom_group: Group of the obstacle geoms (the person's, 1).
        rho_m: Largest distance reported as "in range" [m] (the depth mode's ρ, so both modes
            agree); ``math.inf`` reports every distance (ground truth).
        geom_ids: Explicit obstacle geoms instead of ``geom_group``.

    Attributes:
        geom_ids: The obstacle geoms (G,).
        radius: Their radii [m] (G,).
        half_length: Half length of their segments [m] (G,), 0 for a sphere.
    """

    def __init__(
        self,
        model: mujoco.MjModel,
        geom_group: int = PERSON_GROUP,
        rho_m: float = 0.5,
        geom_ids: np.ndarray | None = None,
    ) -> None:
        if not rho_m > 0.0:
            raise SensingError(f"rho_m must be > 0, got {rho_m}")
        ids = np.flatnonzero(model.geom_group == geom_group) if geom_ids is None else np.asarray(geom_ids, dtype=int)
        if ids.size == 0:
            raise SensingError(f"no obstacle geoms (group {geom_group})")
        types = model.geom_type[ids]
        ok = (types == mujoco.mjtGeom.mjGEOM_CAPSULE) | (types == mujoco.mjtGeom.mjGEOM_SPHERE)
        if not np.all(ok):
            bad = [model.geom(int(g)).name or str(int(g)) for g in ids[~ok]]
            raise SensingError(f"geometric distance supports capsules and spheres only; got other types for {bad}")
        self.model = model
        self.geom_ids = ids
        self.rho_m = float(rho_m)
        self.radius = model.geom_size[ids, 0].copy()
        self.half_length = np.where(types == mujoco.mjtGeom.mjGEOM_CAPSULE, model.geom_size[ids, 1], 0.0)
        # Flat indices of each geom's local z axis (column 2 of its row-major xmat) and the half
        # lengths as a column: ``segments`` gathers with one ``take`` instead of fancy indexing.
        self._axis_index = ids[:, None] * 9 + np.array([2, 5, 8])
        self._half_col = self.half_length[:, None].copy()
        self._ids = ids.astype(np.int64)
        self._a, self._b = np.empty((ids.size, 3)), np.empty((ids.size, 3))  # segment scratch of the kernel

    def segments(self, data: mujoco.MjData) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Ends A, B (G, 3) and radii (G,) of the obstacle geoms in the base frame [m]."""
        centre = data.geom_xpos.take(self.geom_ids, axis=0)
        axis = data.geom_xmat.take(self._axis_index)  # local z axis in the world, (G, 3)
        offset = axis * self._half_col
        return centre - offset, centre + offset, self.radius

    def _closest(self, data: mujoco.MjData, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Distance (K,) and closest point (K, 3) of each point [m] (K, 3): :meth:`segments` and the kernel at once."""
        return closest_on_geoms_kernel(
            points, data.geom_xpos, data.geom_xmat, self._ids, self.half_length, self.radius, self._a, self._b
        )

    def compute(
        self, data: mujoco.MjData, control_points: Mapping[str, np.ndarray], stamp_s: float | None = None
    ) -> DistanceResult:
        """Closest obstacle point of every control point in the state ``data`` (after ``mj_kinematics``).

        Args:
            data: Simulation state (geom poses are read, not recomputed).
            control_points: Control point positions [m] in the base frame, by frame name.
            stamp_s: Time of the query [s]; default ``data.time``.

        Returns:
            :class:`DistanceResult` with ``valid_fraction = 1`` and ``blind = False``.
        """
        names = list(control_points)
        points = np.array([np.asarray(control_points[n], dtype=float) for n in names]) if names else np.empty((0, 3))
        return self.compute_at(data, names, points, stamp_s)

    def compute_at(
        self, data: mujoco.MjData, names: Sequence[str], points: np.ndarray, stamp_s: float | None = None
    ) -> DistanceResult:
        """:meth:`compute` of the points ``points`` [m] (K, 3), float64, named ``names``."""
        readings: dict[str, ObstacleReading] = {}
        if names:
            dist, closest = self._closest(data, points)
            for i, name in enumerate(names):
                if dist[i] <= self.rho_m:
                    readings[name] = ObstacleReading(float(dist[i]), closest[i], True)
                else:
                    readings[name] = ObstacleReading.nothing()
        return DistanceResult(
            readings=readings,
            valid_fraction=1.0,
            blind=False,
            stamp_s=float(data.time) if stamp_s is None else float(stamp_s),
        )

    def distances(self, data: mujoco.MjData, control_points: Mapping[str, np.ndarray]) -> dict[str, float]:
        """True distance per control point [m], whatever ρ (for metrics)."""
        names = list(control_points)
        if not names:
            return {}
        P = np.array([np.asarray(control_points[n], dtype=float) for n in names])
        return self.distances_at(data, names, P)

    def distances_at(self, data: mujoco.MjData, names: Sequence[str], points: np.ndarray) -> dict[str, float]:
        """:meth:`distances` of the points ``points`` [m] (K, 3), float64, named ``names``."""
        dist, _ = self._closest(data, points)
        return dict(zip(names, dist.tolist(), strict=True))


def closest_on_capsules(
    points: np.ndarray, a: np.ndarray, b: np.ndarray, radius: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Distance from each point to the union of capsules, and the closest surface point.

    Args:
        points: Query points [m]. Shape (K, 3).
        a: Capsule segment starts [m]. Shape (G, 3).
        b: Capsule segment ends [m] (= ``a`` for spheres). Shape (G, 3).
        radius: Radii [m]. Shape (G,).

    Returns:
        Distances [m], shape (K,) (0 inside a capsule), and closest points [m], shape (K, 3)
        (the query point itself when inside).
    """
    ab = b - a  # (G, 3)
    ab2 = np.einsum("gi,gi->g", ab, ab)
    ap = points[:, None, :] - a[None, :, :]  # (K, G, 3)
    with np.errstate(invalid="ignore", divide="ignore"):
        tpar = np.where(ab2 > 0.0, np.einsum("kgi,gi->kg", ap, ab) / np.where(ab2 > 0.0, ab2, 1.0), 0.0)
    tpar = np.clip(tpar, 0.0, 1.0)
    c = a[None, :, :] + tpar[..., None] * ab[None, :, :]  # (K, G, 3)
    pc = points[:, None, :] - c
    axis_dist = np.sqrt(np.einsum("kgi,kgi->kg", pc, pc))
    surface = axis_dist - radius[None, :]
    best = np.argmin(surface, axis=1)  # (K,)
    k = np.arange(points.shape[0])
    d_best = surface[k, best]
    c_best = c[k, best]
    pc_best = pc[k, best]
    n_best = axis_dist[k, best]
    closest = np.where(
        (d_best > 0.0)[:, None],
        c_best + radius[best][:, None] * pc_best / np.maximum(n_best, 1e-12)[:, None],
        points,
    )
    return np.maximum(d_best, 0.0), closest

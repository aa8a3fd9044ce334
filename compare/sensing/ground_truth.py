r"""The ground truth of a simulated run: the true distance of each control point to the person [m], no ρ cut.

Called with a kinematics snapshot, :class:`GroundTruth` gives the distances at that instant
(the capsules' poses read from ``MjData`` now). Over a run, :meth:`GroundTruth.record` keeps at
each step what the distance is a function of, the control points and the capsules' poses, and
:meth:`GroundTruth.recorded` computes every recorded step in one compiled call at the end:
the kernel of a call per step (:func:`~compare.sensing._kernels.closest_on_geoms_kernel`),
so the same numbers bit for bit, without a compiled call per control step.
"""

from __future__ import annotations

import math
from collections.abc import Iterable

import mujoco
import numba
import numpy as np

from compare.sensing._kernels import closest_on_geoms_kernel
from compare.sensing.geometric_distance import GeometricDistance
from robots import Kinematics


@numba.njit(cache=True, nogil=True)
def closest_on_recorded_geoms(
    points: np.ndarray,
    geom_xpos: np.ndarray,
    geom_xmat: np.ndarray,
    half_length: np.ndarray,
    radius: np.ndarray,
    out: np.ndarray,
) -> None:
    """Distance of each step's points to its capsules [m] into ``out`` (S, K), step by step.

    Per step :func:`~compare.sensing._kernels.closest_on_geoms_kernel` on the poses recorded then
    (the recorded rows are the obstacle geoms', in order).

    Args:
        points: Query points of each step [m], (S, K, 3).
        geom_xpos: Each step's ``MjData.geom_xpos`` rows of the obstacle geoms [m], (S, G, 3).
        geom_xmat: Each step's ``MjData.geom_xmat`` rows of the obstacle geoms, (S, G, 9).
        half_length: Half length of each obstacle geom's segment [m], (G,).
        radius: Radii [m], (G,).
        out: Distances [m], (S, K).
    """
    n_geoms = half_length.shape[0]
    rows = np.arange(n_geoms)
    a = np.empty((n_geoms, 3))
    b = np.empty((n_geoms, 3))
    for s in range(points.shape[0]):
        dist, _ = closest_on_geoms_kernel(points[s], geom_xpos[s], geom_xmat[s], rows, half_length, radius, a, b)
        out[s] = dist


class GroundTruth:
    """True distance per control point [m] (module docstring).

    Args:
        model: Scene model (the person's capsules: :class:`GeometricDistance`'s obstacle geoms).
        data: The simulation state whose geom poses are read.
        frames: Control point frames.
    """

    def __init__(self, model: mujoco.MjModel, data: mujoco.MjData, frames: Iterable[str]) -> None:
        self.geometric = GeometricDistance(model, rho_m=math.inf)
        self.data = data
        self.frames = tuple(frames)
        self._points = np.empty((len(self.frames), 3))  # float64 (K, 3), as distances() builds it
        ids = self.geometric.geom_ids
        # The obstacle geoms' rows of MjData (its arrays are fixed): views made once when they are consecutive.
        rows = slice(int(ids[0]), int(ids[-1]) + 1) if bool(np.all(np.diff(ids) == 1)) else None
        self._ids = ids
        self._xpos_rows = None if rows is None else data.geom_xpos[rows]
        self._xmat_rows = None if rows is None else data.geom_xmat[rows]
        self._steps_points = np.empty((0, len(self.frames), 3))
        self._steps_xpos = np.empty((0, ids.size, 3))
        self._steps_xmat = np.empty((0, ids.size, 9))
        self._kept = np.zeros(0, dtype=bool)

    def __call__(self, kin: Kinematics) -> dict[str, float]:
        """The distances now, at the control points of ``kin``."""
        if not self.frames:
            return {}
        kin.frame_positions(self.frames, self._points)
        return self.geometric.distances_at(self.data, self.frames, self._points)

    def start(self, n_steps: int) -> None:
        """Room for a run of ``n_steps`` steps (nothing recorded yet)."""
        self._steps_points = np.empty((n_steps, len(self.frames), 3))
        self._steps_xpos = np.empty((n_steps, *self._steps_xpos.shape[1:]))
        self._steps_xmat = np.empty((n_steps, *self._steps_xmat.shape[1:]))
        self._kept = np.zeros(n_steps, dtype=bool)

    def record(self, i: int, kin: Kinematics) -> None:
        """Keep step ``i``: the control points of ``kin`` and the capsules' poses now."""
        kin.frame_positions(self.frames, self._steps_points[i])
        if self._xpos_rows is not None and self._xmat_rows is not None:
            self._steps_xpos[i] = self._xpos_rows
            self._steps_xmat[i] = self._xmat_rows
        else:
            self._steps_xpos[i] = self.data.geom_xpos[self._ids]
            self._steps_xmat[i] = self.data.geom_xmat[self._ids]
        self._kept[i] = True

    def recorded_points(self, n: int) -> np.ndarray:
        """The control points of steps ``0 .. n-1`` as recorded [m], (n, K, 3); NaN rows at a step not recorded."""
        out = np.full((n, len(self.frames), 3), np.nan)
        kept = np.flatnonzero(self._kept[:n])
        out[kept] = self._steps_points[kept]
        return out

    def recorded(self, n: int) -> dict[str, np.ndarray]:
        """The distances of steps ``0 .. n-1`` [m] per frame, each (n,); NaN at a step not recorded."""
        out = np.full((n, len(self.frames)), np.nan)
        kept = np.flatnonzero(self._kept[:n])
        if kept.size and self.frames:
            g = self.geometric
            dist = np.empty((kept.size, len(self.frames)))
            closest_on_recorded_geoms(
                self._steps_points[kept], self._steps_xpos[kept], self._steps_xmat[kept], g.half_length, g.radius, dist
            )
            out[kept] = dist
        return {name: out[:, k] for k, name in enumerate(self.frames)}

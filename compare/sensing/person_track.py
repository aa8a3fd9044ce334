r"""The person's capsules over a whole run on a time grid, and distances of points to them.

The scripted person does not react to the arm, so its whole motion is known before a run: the
verdict's witnesses and certificate (:mod:`compare.campaign.verdict`) and the violation
analysis look it up here instead of interpolating keyframes at every query.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from compare.sensing.person import Person


@dataclass(frozen=True)
class PersonTrack:
    """The person's capsules sampled on a time grid (computed once, looked up at any time).

    Attributes:
        step_s: Grid step [s].
        a: Capsule segment starts [m]. Shape (T, G, 3).
        b: Capsule segment ends [m] (= ``a`` for spheres). Shape (T, G, 3).
        radius: Capsule radii [m]. Shape (G,).
        names: Geom name of each capsule (axis G).
    """

    step_s: float
    a: np.ndarray
    b: np.ndarray
    radius: np.ndarray
    names: tuple[str, ...] = ()

    @classmethod
    def from_person(cls, person: Person, end_s: float, step_s: float) -> PersonTrack:
        """Sample :meth:`Person.capsule_ends` every ``step_s`` from 0 to ``end_s`` [s] (and two samples past it)."""
        n = max(2, int(math.ceil(end_s / step_s)) + 2)
        caps = person.capsule_ends(np.arange(n) * step_s)
        return cls(float(step_s), caps.a, caps.b, caps.radius, caps.names)

    @property
    def end_s(self) -> float:
        """Time of the last sample [s]."""
        return (self.a.shape[0] - 1) * self.step_s

    def index(self, t: np.ndarray | float) -> np.ndarray:
        """Sample indices of the times ``t`` [s] (nearest sample; held after the end)."""
        return np.clip(np.rint(np.asarray(t, dtype=float) / self.step_s), 0, self.a.shape[0] - 1).astype(int)

    def at(self, t: np.ndarray | float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Capsules (A, B, r) at time(s) ``t`` [s]: shapes (..., G, 3), (..., G, 3), (G,)."""
        k = self.index(t)
        return self.a[k], self.b[k], self.radius

    def speeds(self) -> np.ndarray:
        """Speed of every capsule end between consecutive samples [m/s]: the larger of its two ends. Shape (T-1, G)."""
        va = np.linalg.norm(np.diff(self.a, axis=0), axis=2)
        vb = np.linalg.norm(np.diff(self.b, axis=0), axis=2)
        return np.maximum(va, vb) / self.step_s


PARTS: dict[str, tuple[str, ...]] = {
    "torso": ("torso", "head", "leg"),
    "upper_arm": ("upperarm",),
    "forearm": ("forearm",),
    "hand": ("hand",),
}
"""Body parts of the speed summary, by the words their capsule names contain."""


def max_speeds_by_part(track: PersonTrack) -> dict[str, float]:
    """Fastest capsule end of each body part (:data:`PARTS`) over the track [m/s], at the track's sampling."""
    speeds = track.speeds().max(axis=0) if track.a.shape[0] > 1 else np.zeros(len(track.names))
    out: dict[str, float] = {}
    for part, words in PARTS.items():
        picked = [float(v) for name, v in zip(track.names, speeds, strict=True) if any(w in name for w in words)]
        if picked:
            out[part] = max(picked)
    return out


def capsule_margins(
    points: np.ndarray, a: np.ndarray, b: np.ndarray, radius: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    r"""Signed distance of every point to every capsule, and the outward unit normals.

    .. math:: d_{kg} = \|P_k - C_{kg}\| - r_g,\qquad n_{kg} = \frac{P_k - C_{kg}}{\|P_k - C_{kg}\|}

    with :math:`C_{kg}` the closest point of segment g to :math:`P_k`. :math:`\partial d/\partial P
    = n^T` (the closest point's own motion does not change d to first order). Leading batch
    dimensions (e.g. one set of points and capsules per knot) broadcast.

    Args:
        points: Query points [m]. Shape (..., K, 3).
        a: Segment starts [m]. Shape (..., G, 3).
        b: Segment ends [m]. Shape (..., G, 3).
        radius: Radii [m]. Shape (G,).

    Returns:
        Distances [m] (negative inside a capsule), shape (..., K, G); normals, shape (..., K, G, 3).
    """
    ab = b - a
    ab2 = np.einsum("...gi,...gi->...g", ab, ab)
    ap = points[..., :, None, :] - a[..., None, :, :]
    safe = np.where(ab2 > 0.0, ab2, 1.0)
    tpar = np.clip(np.einsum("...kgi,...gi->...kg", ap, ab) / safe[..., None, :], 0.0, 1.0)
    tpar = tpar * (ab2 > 0.0)[..., None, :]
    diff = ap - tpar[..., None] * ab[..., None, :, :]
    norm = np.sqrt(np.einsum("...kgi,...kgi->...kg", diff, diff))
    normal = diff / np.maximum(norm, 1e-12)[..., None]
    return norm - radius, normal

r"""Fusion of several depth cameras into one obstacle reading per control point (DESIGN §4).

Each camera :math:`c` sorts every point :math:`X` of space (its depth along the optical axis
:math:`z_c(X)`, its nearest pixel :math:`q`, the filtered depth :math:`f_c(q)`):

* **measured**: :math:`X` is the surface point of an obstacle pixel (the person, after the
  arm and the static scene are removed) that has a neighbouring pixel within 5 cm in depth (a
  lone flying pixel is not a surface; its half-line stays hidden space);
* **hidden**: :math:`z_c(X) > f_c(q)` behind an obstacle pixel: unknown, may be obstacle
  (Flacco et al.'s conservative rule, the paper's sec. III);
* **seen free**: in view and range, and either in front of an obstacle surface,
  :math:`z_c(X) < f_c(q) - \tau_c(f_c(q))`, or on the ray of a pixel without obstacle (the
  arm and the static scene removed by the filters, or no return): the premise of the
  one-camera method, where the space behind the arm and the table is free (Flacco et al.;
  :mod:`compare.sensing.self_filter`);
* **unknown**: out of view, nearer than the minimum range or beyond the maximum.

with the allowance :math:`\tau_c(f) = \tau_0 + k\,\sigma_c(f)` (``fusion_tolerance_m`` plus
the self-filter's noise allowance). The fused obstacle set is

.. math::
    \mathcal O = \bigcup_c M_c \;\cup\; \Big(\bigcup_c H_c \cap \bigcap_{c'} \overline{F_{c'}}\Big)

(:math:`M_c` measured, :math:`H_c` hidden, :math:`F_c` seen free by camera :math:`c`): a
measured point always counts; a hidden point counts unless some camera sees it free. The
reading of a control point :math:`P` is the point of :math:`\mathcal O` closest to
:math:`P`, ``occluded`` when it comes from the second part, with the camera that measured it
(or behind whose surface it is hidden).

**Why it keeps the properties of the issue.**

1. *No false far where some camera sees the person.* A person point visible to camera
   :math:`c` (outside the self-filter margin) is in :math:`M_c` up to one pixel footprint, and
   measured points are never removed: the fused distance is at most the truth plus that
   footprint, as with that camera alone.
2. *Shadows seen free elsewhere are dropped.* A point hidden from one camera but seen free by
   another is not in :math:`\mathcal O`: the person standing between camera 1 and the arm no
   longer makes the space around the arm "occupied" when camera 2 sees that space.
3. *Space hidden from every camera stays conservative.* A true person point is never seen free
   by any camera (a ray through it stops at it or before), so a person point hidden behind the
   person (or out of view) in every camera stays in :math:`\mathcal O`: the fused distance
   never exceeds the truth there (to the search's resolution), as with one camera. Each camera's own premise is kept as
   well: space behind the *arm* counts as free for the camera it is hidden from (otherwise
   every control point would read the shadow of its own link), so a person point hidden
   behind the arm from one camera and behind the person from all others is missed, as that
   one camera alone would miss it; a second camera that sees the point measures it (1.).

**Computation.** Per camera the depth-space kernel (:mod:`compare.sensing.depth_distance`)
gives, in one pass over each surveillance box, the closest measured point :math:`e_c` and the
closest point :math:`\delta_c \le e_c` of its hidden half-lines. With :math:`e = \min_c e_c`
(capped at ρ) nothing more is needed unless some :math:`\delta_c < e - h` (:math:`h` =
``fusion_step_m``: a hidden point replaces a measured one only when nearer by more than the
search's resolution). Then that camera's hidden half-lines are searched
(:func:`compare.sensing._fusion_kernel.occluded_search`): nearest half-lines first, each
sampled every :math:`h` in depth outward from its closest approach to :math:`P`; the first
sample no other camera sees free is its candidate. Points nearer to :math:`P` than
:func:`~compare.sensing._fusion_kernel.not_free_bounds` of another camera are skipped (that
camera sees them free), which in most frames ends the search before it starts. A hidden
reading is thus exact to about one step (1 cm); a sample budget bounds the work, after which
the remaining half-lines count unclipped (conservative, as with one camera).

The self-filter runs per camera with that camera's margin and noise
(:class:`compare.sensing.pipeline.DepthRig`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from compare.loop.robot_io import CameraModel, DepthFrame
from compare.sensing._fusion_kernel import not_free_bounds, occluded_search
from compare.sensing.camera import DepthNoise, base_to_sensor, sensor_to_base, valid_fraction
from compare.sensing.depth_distance import CameraEvaluation, DepthDistance
from compare.sensing.exceptions import SensingError
from compare.sensing.results import DistanceResult, ObstacleReading


@dataclass(frozen=True)
class FusionSettings:
    r"""Parameters of the fusion (``[sensor]`` ``fusion_step_m`` and ``fusion_tolerance_m``).

    Attributes:
        step_m: Sampling step along a hidden half-line, in depth [m].
        tolerance_m: :math:`\tau_0`: a point is seen free only this much in front of a surface [m].
        noise_allowance: :math:`k`: the allowance grows by this many σ(d) of each camera's noise.
        max_samples: Sample budget per control point and camera; beyond it the remaining
            half-lines count unclipped (conservative).
    """

    step_m: float = 0.01
    tolerance_m: float = 0.002
    noise_allowance: float = 5.0
    max_samples: int = 200_000

    def __post_init__(self) -> None:
        if not (math.isfinite(self.step_m) and self.step_m > 0.0):
            raise SensingError(f"fusion step must be > 0, got {self.step_m}")
        if not (math.isfinite(self.tolerance_m) and self.tolerance_m >= 0.0):
            raise SensingError(f"fusion tolerance must be >= 0, got {self.tolerance_m}")
        if self.max_samples < 1:
            raise SensingError(f"max_samples must be >= 1, got {self.max_samples}")


def _relative(from_cam: CameraModel, to_cam: CameraModel) -> tuple[np.ndarray, np.ndarray]:
    """(R, t) mapping points of ``from_cam``'s sensor frame to ``to_cam``'s: x' = R x + t."""
    ta, tb = from_cam.transform_base_to_camera, to_cam.transform_base_to_camera
    rot = tb[:3, :3].T @ ta[:3, :3]
    return rot, tb[:3, :3].T @ (ta[:3, 3] - tb[:3, 3])


class DepthFusion:
    """One reading per control point from several cameras' filtered frames (module docstring).

    Args:
        distances: Each camera's :class:`DepthDistance` (same ρ; ``min_support`` 1), in order.
        noises: Each camera's noise model (for the free-space allowance).
        settings: Fusion parameters.

    Raises:
        SensingError: Fewer than two cameras, cameras with different ρ, or ``min_support`` > 1.
    """

    def __init__(
        self,
        distances: Sequence[DepthDistance],
        noises: Sequence[DepthNoise] | None = None,
        settings: FusionSettings | None = None,
    ) -> None:
        self.distances = list(distances)
        if len(self.distances) < 2:
            raise SensingError("fusion needs at least two cameras")
        if len({d.rho_m for d in self.distances}) != 1:
            raise SensingError("every camera of a rig must use the same rho_m")
        if any(d.min_support != 1 for d in self.distances):
            raise SensingError("min_support > 1 is supported with one camera only")
        names = [d.name or f"camera_{i}" for i, d in enumerate(self.distances)]
        if len(set(names)) != len(names):
            raise SensingError(f"camera names must be unique, got {names}")
        self.names = names
        self.noises = list(noises) if noises is not None else [DepthNoise() for _ in self.distances]
        if len(self.noises) != len(self.distances):
            raise SensingError("one noise model per camera")
        self.settings = settings or FusionSettings()
        self.rho_m = self.distances[0].rho_m
        cams = [d.camera for d in self.distances]
        s = self.settings
        self._others: list[tuple[list[int], np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = []
        for c, cam in enumerate(cams):
            others = [m for m in range(len(cams)) if m != c]
            pairs = [_relative(cam, cams[m]) for m in others]
            rot = np.ascontiguousarray(np.array([r for r, _ in pairs]))
            trans = np.ascontiguousarray(np.array([t for _, t in pairs]))
            intr = np.array(
                [
                    [o.fx, o.fy, o.cx, o.cy, o.width, o.height, o.min_range_m, o.max_range_m]
                    for o in (cams[m] for m in others)
                ],
                dtype=float,
            )
            tau = np.array(
                [
                    [s.tolerance_m, s.noise_allowance * self.noises[m].std_m, float(self.noises[m].proportional)]
                    for m in others
                ],
                dtype=float,
            )
            self._others.append((others, rot, trans, intr, tau))
        self._work = [np.empty((6, cam.width * cam.height)) for cam in cams]
        self.last_samples = 0
        """Samples tested by the last :meth:`compute` (a cost diagnostic)."""

    def compute(
        self,
        frames: Sequence[DepthFrame],
        control_points: Mapping[str, np.ndarray],
        valid_fractions: Sequence[float] | None = None,
        per_camera: bool = False,
    ) -> DistanceResult:
        """The fused reading of every control point.

        Args:
            frames: Each camera's filtered frame (arm and static scene removed), in order.
            control_points: Control point positions [m] in the base frame, by frame name.
            valid_fractions: Each camera's raw-frame valid fraction (default: of ``frames``).
            per_camera: Also return each camera's own result (``DistanceResult.cameras``).

        Returns:
            The fused :class:`DistanceResult`: ``valid_fraction`` the smallest camera's,
            ``blind`` if any camera is blind, ``stamp_s`` the oldest frame's.
        """
        if len(frames) != len(self.distances):
            raise SensingError(f"expected {len(self.distances)} frames, got {len(frames)}")
        scan = self._scan(frames, control_points, valid_fractions)
        best = _Best.measured(scan, self.rho_m, self.settings.step_m)
        samples = 0
        for c in np.flatnonzero(best.needs_search(scan).any(axis=1)):
            samples += self._search_camera(int(c), frames, scan, best)
        self.last_samples = samples
        cameras: tuple[DistanceResult, ...] = ()
        if per_camera:
            cameras = tuple(
                d.result(f, scan.names, _evaluation(p, box, raw), vf)
                for d, f, p, (box, raw), vf in zip(
                    self.distances, frames, scan.p_sensor, scan.raw, scan.fractions, strict=True
                )
            )
        return DistanceResult(
            readings=self._readings(scan, best),
            valid_fraction=min(scan.fractions),
            blind=any(vf < d.blind_fraction for vf, d in zip(scan.fractions, self.distances, strict=True)),
            stamp_s=min(f.stamp_s for f in frames),
            pixels_visited=int(sum(raw[5].sum() for _, raw in scan.raw)),
            out_of_view=tuple(n for k, n in enumerate(scan.names) if not scan.seen[:, k].any()),
            cameras=cameras,
        )

    def _scan(
        self,
        frames: Sequence[DepthFrame],
        control_points: Mapping[str, np.ndarray],
        valid_fractions: Sequence[float] | None,
    ) -> _Scan:
        """Every camera's depth-space scan of every control point (measured points and hidden half-lines)."""
        names = list(control_points)
        p_base = np.array([np.asarray(control_points[n], dtype=float).reshape(3) for n in names]).reshape(-1, 3)
        fractions = [
            valid_fraction(f) if valid_fractions is None else float(valid_fractions[c]) for c, f in enumerate(frames)
        ]
        p_sensor = [base_to_sensor(d.camera, p_base) for d in self.distances]
        raw = [d.scan(f, p, measured=True) for d, f, p in zip(self.distances, frames, p_sensor, strict=True)]
        boxes = [box for box, _ in raw]
        return _Scan(
            names=names,
            p_sensor=p_sensor,
            raw=raw,
            fractions=fractions,
            delta=np.sqrt(np.array([r[0] for _, r in raw])),  # (N, K) hidden half-lines
            measured=np.sqrt(np.array([r[6] for _, r in raw])),  # (N, K) surface points
            seen=np.array([box[:, 0] < box[:, 1] for box in boxes]),
        )

    def _search_camera(self, c: int, frames: Sequence[DepthFrame], scan: _Scan, best: _Best) -> int:
        """Search camera ``c``'s hidden half-lines for points no other camera sees free; returns the samples.

        Each control point whose hidden distance may beat the best so far by more than the
        search's resolution, and is not within every other camera's seen-free bound, is searched
        (:func:`~compare.sensing._fusion_kernel.occluded_search`); a hit replaces its best.
        """
        others, rot, trans, intr, tau = self._others[c]
        delta = scan.delta
        bounds = np.zeros(len(scan.names))
        for j, m in enumerate(others):
            np.maximum(bounds, not_free_bounds(scan.p_sensor[m], delta[m], best.radius, intr[j], tau[j]), out=bounds)
        limit = best.radius - best.margin
        todo = np.flatnonzero(scan.seen[c] & (delta[c] < limit) & (bounds < limit))
        if todo.size == 0:
            return 0
        owner = self.distances[c]
        depth = _contiguous(frames[c].depth_m)
        other_depths = tuple(_contiguous(frames[m].depth_m) for m in others)
        box = scan.raw[c][0]
        samples = 0
        for k in todo:
            found, x, y, z, n, _ = occluded_search(
                depth,
                box[k],
                owner._xn64,
                owner._yn64,
                owner._inv_rr,
                owner.camera.min_range_m,
                owner.camera.max_range_m,
                scan.p_sensor[c][k],
                float(bounds[k]),
                float(best.radius[k] - best.margin[k]),
                self.settings.step_m,
                self.settings.max_samples,
                rot,
                trans,
                intr,
                tau,
                other_depths,
                self._work[c],
            )
            samples += n
            if found < best.radius[k] - best.margin[k]:
                best.take_hidden(int(k), c, found, np.array([x, y, z]))
        return samples

    def _readings(self, scan: _Scan, best: _Best) -> dict[str, ObstacleReading]:
        """The reading of every control point from the best point found (measured or hidden)."""
        readings = {}
        for k, name in enumerate(scan.names):
            if not best.distance[k] <= self.rho_m:
                readings[name] = ObstacleReading.nothing()
                continue
            c = int(best.camera[k])
            hidden = best.hidden_points.get(k)
            if hidden is None:
                raw = scan.raw[c][1]
                ed = raw[9][k]
                hidden_or_surface = np.array([raw[7][k] * ed, raw[8][k] * ed, ed])
            else:
                hidden_or_surface = hidden
            point = sensor_to_base(self.distances[c].camera, hidden_or_surface)
            readings[name] = ObstacleReading(float(best.distance[k]), point, True, hidden is not None, self.names[c])
        return readings


@dataclass
class _Scan:
    """Every camera's scan of the control points (:meth:`DepthFusion._scan`).

    Attributes:
        names: Control point names (K).
        p_sensor: Control points in each camera's sensor frame [m], N × (K, 3).
        raw: Each camera's (boxes, raw arrays) of :meth:`DepthDistance.scan`.
        fractions: Each camera's valid fraction.
        delta: Distance to each camera's hidden half-lines [m], (N, K).
        measured: Distance to each camera's closest measured point [m], (N, K).
        seen: Control point in each camera's view, (N, K).
    """

    names: list[str]
    p_sensor: list[np.ndarray]
    raw: list[tuple[np.ndarray, tuple[np.ndarray, ...]]]
    fractions: list[float]
    delta: np.ndarray
    measured: np.ndarray
    seen: np.ndarray


@dataclass
class _Best:
    """The best point so far per control point: its distance [m], camera and (hidden ones) the point.

    ``radius`` is the search radius (the best distance capped at ρ) and ``margin`` what a hidden
    point must beat it by (the search's step while the best is a measured point within ρ).
    """

    distance: np.ndarray
    camera: np.ndarray
    radius: np.ndarray
    margin: np.ndarray
    hidden_points: dict[int, np.ndarray]

    @classmethod
    def measured(cls, scan: _Scan, rho: float, step: float) -> _Best:
        """Start from the closest surface point over all cameras (never dropped)."""
        camera = np.argmin(scan.measured, axis=0)
        distance = scan.measured[camera, np.arange(len(scan.names))]
        # A hidden point replaces a measured one only if nearer by more than the search's resolution.
        margin = np.where(distance <= rho, step, 0.0)
        return cls(distance, camera, np.minimum(distance, rho), margin, {})

    def needs_search(self, scan: _Scan) -> np.ndarray:
        """(N, K): camera's hidden half-lines may hold a point nearer than the best (by the margin)."""
        return scan.seen & (scan.delta < self.radius - self.margin)

    def take_hidden(self, k: int, camera: int, distance: float, point: np.ndarray) -> None:
        """Control point ``k``'s best is now a hidden point of ``camera``."""
        self.radius[k] = self.distance[k] = distance
        self.margin[k] = 0.0
        self.camera[k] = camera
        self.hidden_points[k] = point


def _evaluation(p: np.ndarray, boxes: np.ndarray, raw: tuple[np.ndarray, ...]) -> CameraEvaluation:
    """A :class:`CameraEvaluation` from :meth:`DepthDistance.scan`'s raw arrays (distances from their squares)."""
    d2, a, b, s, hidden, counts, e2, ea, eb, ed = raw
    return CameraEvaluation(
        p_sensor=p,
        boxes=boxes,
        seen=boxes[:, 0] < boxes[:, 1],
        distance_m=np.sqrt(d2),
        point_sensor=np.stack([a * s, b * s, s], axis=1),
        hidden=hidden,
        counts=counts,
        measured_m=np.sqrt(e2),
        measured_point_sensor=np.stack([ea * ed, eb * ed, ed], axis=1),
    )


def _contiguous(depth: np.ndarray) -> np.ndarray:
    if depth.dtype == np.float32 and depth.flags.c_contiguous:
        return depth
    return np.ascontiguousarray(depth, dtype=np.float32)

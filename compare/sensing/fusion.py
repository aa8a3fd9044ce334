r"""Fusion of several depth cameras into one obstacle reading per control point (docs/design.md §4).

Each camera :math:`c` sorts every point :math:`X` of space (its depth along the optical axis
:math:`z_c(X)`, its nearest pixel :math:`q`, the filtered depth :math:`f_c(q)` and the raw
return :math:`r_c(q)` before the filters):

* **measured**: :math:`X` is the surface point of an obstacle pixel (the person, after the
  arm and the static scene are removed) that has a neighbouring pixel within 5 cm in depth (a
  lone flying pixel is not a surface; its half-line stays hidden space);
* **hidden**: :math:`z_c(X) > f_c(q)` behind an obstacle pixel: unknown, may be obstacle
  (Flacco et al.'s conservative rule, the paper's sec. III);
* **seen free**: in view and range, and in front of the pixel's raw return,
  :math:`z_c(X) < r_c(q) - \tau_c(r_c(q))`, whatever the return is (the person, the arm or the
  static scene: the filters decide what is an obstacle, not what was seen);
* **unknown**: everything else: behind the arm or the static scene, on the ray of a pixel
  without a return in range (dropout; nothing is seen free there), out of view, nearer than
  the minimum range or beyond the maximum.

with the allowance :math:`\tau_c(r) = \tau_0 + k\,\sigma_c(r)` (``fusion_tolerance_m`` plus
the self-filter's noise allowance). The fused obstacle set is

.. math::
    \mathcal O = \bigcup_c M_c \;\cup\; \Big(\bigcup_c H_c \cap \bigcap_{c'} \overline{F_{c'}}\Big)

(:math:`M_c` measured, :math:`H_c` hidden, :math:`F_c` seen free by camera :math:`c`): a
measured point always counts; a hidden point counts unless some camera sees it free. Space
behind the arm or the static scene creates no hidden half-line of its own (each camera keeps
the premise of the one-camera method, Flacco et al.; :mod:`compare.sensing.self_filter`), but
it clears nothing either. The reading of a control point :math:`P` is the point of
:math:`\mathcal O` closest to :math:`P`, ``occluded`` when it comes from the second part, with
the camera that measured it (or behind whose surface it is hidden).

**What is guaranteed** (:math:`X^*` the person point closest to :math:`P`, :math:`h` =
``fusion_step_m``, a pixel footprint :math:`z / f`):

1. *No false far where some camera sees the person.* If camera :math:`c` sees :math:`X^*`
   (outside its self-filter margin), :math:`X^*` is in :math:`M_c` up to one pixel footprint,
   and measured points are never removed: the fused distance is at most the truth plus that
   footprint, as with that camera alone.
2. *No false far where no camera sees the person, if one camera has it behind the person.* A
   person point is seen free by no camera: a ray through it returns at it or before it, or
   returns nothing (unknown), or it is out of view. So if :math:`X^*` lies behind the person
   for some camera (:math:`X^* \in H_c`), whatever hides it from the others (the person, the
   arm, the static scene, dropout, the view's edge), it stays in :math:`\mathcal O`; the
   search finds a sample within :math:`h` of it along that camera's ray: the fused distance is
   at most the truth plus about :math:`h` (plus a pixel footprint), and the reading is
   ``occluded`` unless a measured point is as near.
3. *Shadows seen free elsewhere are dropped.* A point hidden from one camera that another sees
   in front of a return is not in :math:`\mathcal O`. Shadows near the arm are mostly kept:
   the arm's own volume and what lies behind it are unknown to the cameras that see the arm,
   and so is every ray without a return.

**What is not.** A person point hidden behind the arm or the static scene from *every* camera
(or within every camera's self-filter margin of the arm, which removes it with the arm) is in
no :math:`H_c` and is missed, as with one camera: Flacco's premise that the arm's shadow is
free. A camera that sees it measures it (1.).

**Computation.** Per camera the depth-space kernel (:mod:`compare.sensing.depth_distance`)
gives, in one pass over each surveillance box, the closest measured point :math:`e_c` and the
closest point :math:`\delta_c \le e_c` of its hidden half-lines. With :math:`e = \min_c e_c`
(capped at ρ) nothing more is needed unless some :math:`\delta_c < e - h` (a hidden point
replaces a measured one only when nearer by more than the search's resolution). Then the
point at :math:`\delta_c` itself is tested first: when no other camera sees it free, it is the
answer (the search's first sample would be it). Otherwise that camera's hidden half-lines are
searched
(:func:`compare.sensing._fusion_kernel.occluded_search`): nearest half-lines first, each
sampled every :math:`h` in depth outward from its closest approach to :math:`P`; the first
sample no other camera sees free (tested on that camera's raw frame) is its candidate. Points
nearer to :math:`P` than :func:`~compare.sensing._fusion_kernel.not_free_bounds` of another
camera are skipped: a lower bound of the distance to everything that camera does not see free,
its arm's and static scene's shadows and its rays without return included. A control point
inside its own link, behind the arm's surface for a camera, gets 0 from that camera without a
scan. A hidden reading is thus exact to about one step (1 cm); a sample budget bounds the work,
after which the remaining half-lines count unclipped (conservative, as with one camera).

Without the raw frames (:meth:`DepthFusion.compute`'s ``raw_frames``) the filtered ones stand
in: a removed pixel then sees nothing free (sound, more conservative). The self-filter runs per
camera with that camera's margin and noise (:class:`compare.sensing.pipeline.DepthRig`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from compare.sensing._fusion_kernel import not_free_bounds, occluded_search, seen_free
from compare.sensing.camera import DepthNoise, base_to_sensor, sensor_to_base, valid_fraction
from compare.sensing.depth_distance import CameraEvaluation, DepthDistance
from compare.sensing.exceptions import SensingError
from compare.sensing.frames import CameraModel, DepthFrame
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
        raw_frames: Sequence[DepthFrame] | None = None,
    ) -> DistanceResult:
        """The fused reading of every control point.

        Args:
            frames: Each camera's filtered frame (arm and static scene removed), in order.
            control_points: Control point positions [m] in the base frame, by frame name.
            valid_fractions: Each camera's raw-frame valid fraction (default: of ``frames``).
            per_camera: Also return each camera's own result (``DistanceResult.cameras``).
            raw_frames: Each camera's frame before the filters, in order: what it sees free (in
                front of every return, the arm's and the static scene's included). Default
                ``frames``: a removed pixel then sees nothing free (sound, more conservative).

        Returns:
            The fused :class:`DistanceResult`: ``valid_fraction`` the smallest camera's,
            ``blind`` if any camera is blind, ``stamp_s`` the oldest frame's.
        """
        if len(frames) != len(self.distances):
            raise SensingError(f"expected {len(self.distances)} frames, got {len(frames)}")
        raws = self._raw_depths(frames if raw_frames is None else raw_frames)
        scan = self._scan(frames, control_points, valid_fractions)
        best = _Best.measured(scan, self.rho_m, self.settings.step_m)
        samples = 0
        for c in np.flatnonzero(best.needs_search(scan).any(axis=1)):
            samples += self._search_camera(int(c), frames, raws, scan, best)
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

    def _raw_depths(self, raw_frames: Sequence[DepthFrame]) -> list[np.ndarray]:
        """Each camera's raw depth image (float32, C order) for the seen-free test."""
        if len(raw_frames) != len(self.distances):
            raise SensingError(f"expected {len(self.distances)} raw frames, got {len(raw_frames)}")
        raws = [_contiguous(f.depth_m) for f in raw_frames]
        for d, raw in zip(self.distances, raws, strict=True):
            if raw.shape != (d.camera.height, d.camera.width):
                raise SensingError(f"raw frame shape {raw.shape} != camera ({d.camera.height}, {d.camera.width})")
        return raws

    def _search_camera(
        self, c: int, frames: Sequence[DepthFrame], raws: Sequence[np.ndarray], scan: _Scan, best: _Best
    ) -> int:
        """Search camera ``c``'s hidden half-lines for points no other camera sees free; returns the samples.

        Each control point whose hidden distance may beat the best so far by more than the
        search's resolution, and is not within another camera's seen-free bound, is searched
        (:func:`~compare.sensing._fusion_kernel.occluded_search`); a hit replaces its best.
        """
        others, rot, trans, intr, tau = self._others[c]
        limit = best.radius - best.margin
        todo = np.flatnonzero(scan.seen[c] & (scan.delta[c] < limit))
        if todo.size == 0:
            return 0
        bounds = self._seen_free_bounds(c, todo, raws, scan, best.radius)
        keep = bounds < limit[todo]
        todo, bounds = todo[keep], bounds[keep]
        owner = self.distances[c]
        depth = _contiguous(frames[c].depth_m)
        other_depths = tuple(raws[m] for m in others)
        box = scan.raw[c][0]
        samples = 0
        for k, radius_lo in zip(todo, bounds, strict=True):
            nearest = self._nearest_hidden(c, int(k), scan)
            if nearest is not None and not seen_free(nearest, rot, trans, intr, tau, other_depths):
                # The nearest hidden point of all is not seen free: the search's first sample, its answer.
                samples += 1
                best.take_hidden(int(k), c, float(scan.delta[c, k]), nearest)
                continue
            found, x, y, z, n, _ = occluded_search(
                depth,
                box[k],
                owner._xn64,
                owner._yn64,
                owner._inv_rr,
                owner.camera.min_range_m,
                owner.camera.max_range_m,
                scan.p_sensor[c][k],
                float(radius_lo),
                float(limit[k]),
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
            if found < limit[k]:
                best.take_hidden(int(k), c, found, np.array([x, y, z]))
        return samples

    @staticmethod
    def _nearest_hidden(c: int, k: int, scan: _Scan) -> np.ndarray | None:
        """Camera ``c``'s closest hidden point to control point ``k`` (sensor frame [m]), None if on a surface."""
        d2, a, b, s, hidden = scan.raw[c][1][:5]
        return np.array([a[k] * s[k], b[k] * s[k], s[k]]) if hidden[k] else None

    def _seen_free_bounds(
        self, c: int, todo: np.ndarray, raws: Sequence[np.ndarray], scan: _Scan, radius: np.ndarray
    ) -> np.ndarray:
        """Per control point of ``todo``: every point nearer than this [m] is seen free by some camera other than ``c``.

        The largest of the other cameras' :func:`~compare.sensing._fusion_kernel.not_free_bounds`
        (each computed on that camera's raw frame).
        """
        others, _, _, intr, tau = self._others[c]
        bounds = np.zeros(todo.size)
        for j, m in enumerate(others):
            d = self.distances[m]
            bound = not_free_bounds(
                scan.p_sensor[m], raws[m], todo, d._xn64, d._yn64, d._inv_rr, radius,
                intr[j : j + 1], tau[j : j + 1],
            )  # fmt: skip
            np.maximum(bounds, bound, out=bounds)
        return bounds

    def _readings(self, scan: _Scan, best: _Best) -> dict[str, ObstacleReading]:
        """The reading of every control point from the best point found (measured or hidden)."""
        readings = {}
        for k, name in enumerate(scan.names):
            if not best.distance[k] <= self.rho_m:
                readings[name] = ObstacleReading.nothing()
                continue
            c = int(best.camera[k])
            hidden = best.hidden_points.get(k)
            raw = scan.raw[c][1]
            ed = raw[9][k]
            surface = np.array([raw[7][k] * ed, raw[8][k] * ed, ed])  # camera c's nearest measured point
            point = sensor_to_base(self.distances[c].camera, surface if hidden is None else hidden)
            seen = None
            if hidden is not None and np.isfinite(raw[6][k]):
                seen = sensor_to_base(self.distances[c].camera, surface)
            readings[name] = ObstacleReading(
                float(best.distance[k]), point, True, hidden is not None, self.names[c], seen
            )
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

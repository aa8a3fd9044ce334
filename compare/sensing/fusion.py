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
        names = list(control_points)
        k_points = len(names)
        p_base = np.array([np.asarray(control_points[n], dtype=float).reshape(3) for n in names]).reshape(-1, 3)
        fractions = [
            valid_fraction(f) if valid_fractions is None else float(valid_fractions[c]) for c, f in enumerate(frames)
        ]
        dists = self.distances
        p_sensor = [base_to_sensor(d.camera, p_base) for d in dists]
        scans = [d.scan(f, p, measured=True) for d, f, p in zip(dists, frames, p_sensor, strict=True)]
        boxes = [box for box, _ in scans]
        delta = np.sqrt(np.array([raw[0] for _, raw in scans]))  # (N, K) hidden half-lines
        measured = np.sqrt(np.array([raw[6] for _, raw in scans]))  # (N, K) surface points
        seen = np.array([box[:, 0] < box[:, 1] for box in boxes])
        rho = self.rho_m
        # Measured: the closest surface point over all cameras (never dropped).
        best_cam = np.argmin(measured, axis=0)
        best = measured[best_cam, np.arange(k_points)]
        hidden_points: dict[int, np.ndarray] = {}
        radius = np.minimum(best, rho)
        # A hidden point replaces a measured one only if nearer by more than the search's resolution.
        margin = np.where(best <= rho, self.settings.step_m, 0.0)
        need = seen & (delta < radius - margin)
        samples = 0
        for c in np.flatnonzero(need.any(axis=1)):
            others, rot, trans, intr, tau = self._others[c]
            bounds = np.zeros(k_points)
            for j, m in enumerate(others):
                np.maximum(bounds, not_free_bounds(p_sensor[m], delta[m], radius, intr[j], tau[j]), out=bounds)
            todo = np.flatnonzero(seen[c] & (delta[c] < radius - margin) & (bounds < radius - margin))
            if todo.size == 0:
                continue
            owner = dists[c]
            depth = _contiguous(frames[c].depth_m)
            other_depths = tuple(_contiguous(frames[m].depth_m) for m in others)
            for k in todo:
                found, x, y, z, n, _ = occluded_search(
                    depth,
                    boxes[c][k],
                    owner._xn64,
                    owner._yn64,
                    owner._inv_rr,
                    owner.camera.min_range_m,
                    owner.camera.max_range_m,
                    p_sensor[c][k],
                    float(bounds[k]),
                    float(radius[k] - margin[k]),
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
                if found < radius[k] - margin[k]:
                    radius[k] = best[k] = found
                    margin[k] = 0.0
                    best_cam[k] = c
                    hidden_points[int(k)] = np.array([x, y, z])
        self.last_samples = samples
        readings = {}
        for k, name in enumerate(names):
            if not best[k] <= rho:
                readings[name] = ObstacleReading.nothing()
                continue
            c = int(best_cam[k])
            hidden = hidden_points.get(k)
            if hidden is None:
                raw = scans[c][1]
                ed = raw[9][k]
                hidden_or_surface = np.array([raw[7][k] * ed, raw[8][k] * ed, ed])
            else:
                hidden_or_surface = hidden
            point = sensor_to_base(dists[c].camera, hidden_or_surface)
            readings[name] = ObstacleReading(float(best[k]), point, True, hidden is not None, self.names[c])
        cameras: tuple[DistanceResult, ...] = ()
        if per_camera:
            cameras = tuple(
                d.result(f, names, _evaluation(p, box, raw), vf)
                for d, f, p, (box, raw), vf in zip(dists, frames, p_sensor, scans, fractions, strict=True)
            )
        return DistanceResult(
            readings=readings,
            valid_fraction=min(fractions),
            blind=any(vf < d.blind_fraction for vf, d in zip(fractions, dists, strict=True)),
            stamp_s=min(f.stamp_s for f in frames),
            pixels_visited=int(sum(raw[5].sum() for _, raw in scans)),
            out_of_view=tuple(n for k, n in enumerate(names) if not seen[:, k].any()),
            cameras=cameras,
        )


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

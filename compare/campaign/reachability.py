r"""A certificate that no motion of the arm could have kept a control point beyond its obstacle threshold.

The verdict's proof of ``unavoidable`` (:mod:`compare.campaign.verdict`). It over-approximates
where a control point can be at each instant, whatever the arm does within its joint velocity
limits, and shows that at some instant the person's capsules, inflated by the safety threshold,
cover all of it.

**Bounds.** A control point c is moved by the joints of its chain, 1..m (base to c), with origins
:math:`o_i` and :math:`o_{m+1} = p_c`. Each :math:`\|o_{k+1} - o_k\|` is a constant of the model
(a joint placement, or the frame's offset in its joint), so with :math:`\ell_i = \sum_{k=i}^{m}
\|o_{k+1} - o_k\|`:

* :math:`\|p_c - o_1\| \le \ell_1` at every configuration, and :math:`o_1` is fixed in the base
  frame: c stays in the ball :math:`W_c = B(o_1, \ell_1)`;
* :math:`\dot p_c = \sum_i \dot q_i\, \hat z_i \times (p_c - o_i)`, so :math:`\|\dot p_c\| \le V_c =
  \sum_{i \le m} \dot q_{i,max}\, \ell_i`: in a time Δt, c moves at most :math:`V_c \Delta t`.

Joint position limits, the walls, the plant's lag and the other control points only shrink the
true set; ignoring them keeps the bound conservative.

**Propagation.** Space is cut into cubes of side δ (about ``[oracle] certificate_voxel_m``; δ is
set just above :math:`V_c \Delta t`, with Δt a whole number of control periods, so that every
:math:`t_k = k\,\Delta t` is an instant the metrics judge and a step moves c less than a cube).
The set :math:`S_k` holds every cube that may contain c at :math:`t_k`:

* :math:`S_0` = the cube of :math:`p_c(0)`;
* :math:`S_{k+1}` = the cubes next to :math:`S_k` (a point moving less than δ stays in its cube or
  a neighbour), inside :math:`W_c` and within :math:`V_c t_{k+1}` of :math:`p_c(0)`, minus the
  cubes *covered* at :math:`t_{k+1}`;
* a cube is covered when all of it lies within :math:`\sigma_s - \epsilon` of the person:
  :math:`\min_g (d(x, \text{segment}_g) - r_g) + \tfrac{\sqrt 3}{2}\delta \le \sigma_s - \epsilon`
  at its centre x (ε the metrics' violation tolerance).

Every motion within the velocity limits is in :math:`S_k` at :math:`t_k` unless it was closer than
:math:`\sigma_s - \epsilon` to the person at some earlier :math:`t_j`. When :math:`S_k` is empty,
every such motion passed the safety threshold by more than the metrics' tolerance at one of the
judged instants: the violation was unavoidable. A set that never empties proves nothing.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

import robots
from compare.sensing.person_track import PersonTrack, capsule_margins


@dataclass(frozen=True)
class ReachBound:
    r"""Where a control point can be, and how fast it can move (module docstring).

    Attributes:
        frame: The control point's frame.
        anchor: :math:`o_1`, the fixed origin of the first joint of its chain [m]. Shape (3,).
        reach_m: :math:`\ell_1`: it stays within this distance of the anchor [m].
        speed_mps: :math:`V_c`: it never moves faster [m/s].
    """

    frame: str
    anchor: np.ndarray
    reach_m: float
    speed_mps: float


def reach_bound(robot: robots.Robot, frame: str) -> ReachBound:
    """The :class:`ReachBound` of control point ``frame`` from the robot's joint placements and velocity limits."""
    model = robot.pin_model
    fid = robot.frame_id(frame)
    chain = [j for j in model.supports[model.frames[fid].parentJoint] if j > 0]  # base to the frame's joint
    links = [float(np.linalg.norm(model.jointPlacements[j].translation)) for j in chain[1:]]
    links.append(float(np.linalg.norm(model.frames[fid].placement.translation)))
    lever = np.cumsum(links[::-1])[::-1]  # ℓ_i: chain length from joint i's origin to the frame
    v_max = np.array([robot.v_max[model.joints[j].idx_v] for j in chain])
    kin = robot.kinematics(robot.home)
    anchor = kin.joint_origins()[model.joints[chain[0]].idx_q] if chain else kin.frame_position(frame)
    return ReachBound(frame, np.array(anchor, dtype=float), float(lever[0]), float(v_max @ lever))


def _structure(radius_m: float, voxel_m: float) -> np.ndarray:
    """Offsets of the cubes whose box lies within ``radius_m`` of the centre cube's box: a boolean kernel."""
    r = int(math.ceil(radius_m / voxel_m)) + 1
    o = np.abs(np.arange(-r, r + 1))
    gap = np.maximum(o - 1, 0) * voxel_m  # box-to-box distance per axis
    dist2 = gap[:, None, None] ** 2 + gap[None, :, None] ** 2 + gap[None, None, :] ** 2
    return dist2 <= radius_m**2 + 1e-15


@dataclass(frozen=True)
class Proof:
    """A certificate found: at ``time_s`` every reachable position of ``frame`` is covered.

    Attributes:
        frame: The control point.
        time_s: The instant [s].
        reach_mps: :math:`V_c` used [m/s].
        voxel_m: δ used [m].
    """

    frame: str
    time_s: float
    reach_mps: float
    voxel_m: float


class ReachableCubes:
    r"""The cubes :math:`S_k` of the module docstring for one control point, advanced step by step.

    Args:
        bound: The control point's reach and speed bounds.
        start: Its position at t = 0 [m]. Shape (3,).
        dt: The control period [s]: a step Δt is a whole number of periods.
        voxel_m: The cube side wanted [m]: δ is set to :math:`(1 + 10^{-6}) V_c \Delta t` with the
            whole number of periods that brings it nearest, so that a step moves the point less
            than one cube.
    """

    def __init__(self, bound: ReachBound, start: np.ndarray, dt: float, voxel_m: float) -> None:
        # A step moves the point at most V Δt = δ / (1 + 1e-6): strictly less than a cube, so the
        # cubes reached are exactly the 26 neighbours (the kernel of _structure).
        self.periods = max(1, round(voxel_m / max(bound.speed_mps * dt, 1e-12)))
        self.step_s = self.periods * dt
        self.voxel_m = max(bound.speed_mps * self.step_s, 1e-6) * (1.0 + 1e-6)
        half = bound.reach_m + self.voxel_m
        self._n = int(math.ceil(2.0 * half / self.voxel_m)) + 1
        self._origin = bound.anchor - half
        axis = np.arange(self._n) * self.voxel_m
        self._centres = self._origin + np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), axis=-1)
        self._slack = 0.5 * math.sqrt(3.0) * self.voxel_m
        self._inside = np.linalg.norm(self._centres - bound.anchor, axis=-1) <= bound.reach_m + self._slack
        self._from_start = np.linalg.norm(self._centres - np.asarray(start, dtype=float), axis=-1) - self._slack
        self._speed = bound.speed_mps
        self._kernel = _structure(bound.speed_mps * self.step_s, self.voxel_m)
        self.steps = 0
        self.cubes = np.zeros((self._n,) * 3, dtype=bool)
        self.cubes[tuple(self._cell(start))] = True

    def _cell(self, point: np.ndarray) -> np.ndarray:
        return np.clip(np.floor((np.asarray(point) - self._origin) / self.voxel_m + 0.5).astype(int), 0, self._n - 1)

    def contains(self, point: np.ndarray) -> bool:
        """Whether the cube holding ``point`` [m] is in the set."""
        return bool(self.cubes[tuple(self._cell(point))])

    @property
    def empty(self) -> bool:
        """No cube left."""
        return not self.cubes.any()

    def advance(self) -> None:
        r"""One step: the cubes next to the set, inside the reach ball and within :math:`V_c t` of the start."""
        self.steps += 1
        near = self._from_start <= self._speed * self.steps * self.step_s  # within V t of the start
        self.cubes = ndimage.binary_dilation(self.cubes, structure=self._kernel) & self._inside & near

    def remove_covered(self, track: PersonTrack, t: float, limit_m: float) -> None:
        """Remove the cubes wholly within ``limit_m`` of the person's surface at time ``t`` [s]."""
        limit = limit_m - self._slack  # a cube is covered when its centre's margin is below this
        if limit <= 0.0:
            return
        a, b, r = track.at(t)
        lo = np.minimum(a, b) - (limit + r)[:, None]
        hi = np.maximum(a, b) + (limit + r)[:, None]
        i0 = np.clip(np.floor((lo.min(axis=0) - self._origin) / self.voxel_m).astype(int), 0, self._n)
        i1 = np.clip(np.ceil((hi.max(axis=0) - self._origin) / self.voxel_m).astype(int) + 1, 0, self._n)
        if np.any(i1 <= i0):
            return
        box = tuple(slice(int(s), int(e)) for s, e in zip(i0, i1, strict=True))
        candidates = self.cubes[box]
        idx = np.nonzero(candidates)
        if not idx[0].size:
            return
        margin = capsule_margins(self._centres[box][idx], a, b, r)[0].min(axis=1)
        candidates[idx] = margin > limit  # a view: writes through to self.cubes


def prove_unavoidable(
    bound: ReachBound,
    start: np.ndarray,
    track: PersonTrack,
    safety_m: float,
    end_s: float,
    dt: float,
    voxel_m: float = 0.04,
    tolerance_m: float = 1e-3,
) -> Proof | None:
    r"""Search the certificate of the module docstring for one control point.

    Args:
        bound: The control point's reach and speed bounds.
        start: Its position at t = 0 [m]. Shape (3,).
        track: The person's capsules over the run.
        safety_m: Its obstacle safety threshold :math:`\sigma_s` [m].
        end_s: The run's duration [s].
        dt: The control period [s] (the metrics' sampling).
        voxel_m: δ [m].
        tolerance_m: ε, the metrics' violation tolerance [m].

    Returns:
        The proof, or None when the reachable set never empties (nothing shown).
    """
    reach = ReachableCubes(bound, start, dt, voxel_m)
    k = 0
    while True:
        t = k * reach.step_s
        reach.remove_covered(track, t, safety_m - tolerance_m)
        if reach.empty:
            return Proof(bound.frame, t, bound.speed_mps, reach.voxel_m)
        k += 1
        if k * reach.step_s > end_s + 1e-9:
            return None
        reach.advance()

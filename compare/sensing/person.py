r"""A person made of capsules, moved along scripted keyframes as MuJoCo mocap bodies.

The person of ``scene_workcell.xml`` has one mocap body for the torso (torso, head and legs,
rigidly attached; its frame on the floor under the torso axis, x = facing direction) and one
mocap body per arm segment (upper arm, forearm, hand, each a capsule along the body's +z axis
from its origin). A :class:`Person` turns keyframes into mocap poses:

* torso position (x, y) and heading (yaw) are interpolated linearly between keyframes (yaw
  along the shorter arc), held before the first and after the last keyframe;
* a hand target is interpolated linearly between keyframes; a keyframe without a target uses
  the hanging-arm position of that keyframe's torso pose, so a hand rises or drops smoothly;
* each arm reaches its hand target (the centre of the hand capsule) with a planar two-link
  inverse kinematics from the shoulder site: upper arm :math:`L_1`, forearm plus half hand
  :math:`L_2`, elbow bent towards a pole direction (down, out and back). With
  :math:`D = \|T - S\|` clamped to :math:`[|L_1 - L_2|,\ \kappa (L_1 + L_2)]` (:data:`REACH_FRACTION`
  :math:`\kappa`: the elbow never straightens, where the elbow's speed would grow without bound
  as :math:`h = \sqrt{L_1^2 - a^2}` has an infinite slope at full stretch),

  .. math::
      a = \frac{L_1^2 - L_2^2 + D^2}{2D},\quad h = \sqrt{L_1^2 - a^2},\quad
      E = S + a\,\hat e + h\,\hat n

  where :math:`\hat e` points from the shoulder to the target and :math:`\hat n` is the pole
  direction made orthogonal to it. An unreachable target is approached as far as the arm
  allows (the hand stops short on the shoulder–target line).

Segment lengths, radii and shoulder positions are read from the model (the MJCF is the single
source of truth). A person with no keyframes is parked far outside the camera's range.

Every pose is computed for many instants at once (:meth:`Person.capsule_ends`, arrays over
time); :meth:`Person.apply` reads the mocap poses of a control step from blocks computed on the
control period's grid, so the per-step cost is one array copy.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

import mujoco
import numpy as np

from compare.sensing.exceptions import SensingError, UnknownSceneElement

_Vec = tuple[float, float, float]

SIDES = ("r", "l")
"""Right and left arm prefixes of the person's body names."""
SEGMENTS = ("upperarm", "forearm", "hand")
"""Arm segments, shoulder to fingertips."""

PARKED_POSITION = (0.0, 50.0)
"""Where a person without keyframes stands (x, y) [m]: beyond the camera range and far plane."""

REACH_FRACTION = 0.9
"""κ: the largest shoulder–hand-centre distance as a share of :math:`L_1 + L_2` (elbow bent ≥ ~50°)."""

# Hanging arm, in the torso frame relative to the shoulder (x forward, y left, z up), before the
# side's mirroring in y: slightly forward and out, 3 cm short of full stretch.
_HANG_OFFSET = (0.05, -0.03)
_HANG_SHORTFALL_M = 0.03
# Elbow pole direction in the torso frame for the right arm (back, out, down); mirrored for the left.
_POLE_RIGHT = (-0.25, -0.5, -1.0)
# Key columns: torso x, y, yaw, right hand target (3), left hand target (3).
_X, _Y, _YAW, _RIGHT, _LEFT = 0, 1, 2, slice(3, 6), slice(6, 9)
# Samples per block of mocap poses computed ahead by :meth:`Person.apply`.
_BLOCK = 256


class KeyframeLike(Protocol):
    """What a keyframe needs (``compare.config.PersonKeyframe`` and :class:`PersonKeyframe` fit)."""

    @property
    def t(self) -> float:
        """Time [s]."""

    @property
    def position(self) -> tuple[float, float]:
        """Torso axis on the floor (x, y) [m]."""

    @property
    def yaw(self) -> float:
        """Heading [rad]."""

    @property
    def right_hand(self) -> tuple[float, float, float] | None:
        """Right hand target [m] or None."""

    @property
    def left_hand(self) -> tuple[float, float, float] | None:
        """Left hand target [m] or None."""


@dataclass(frozen=True)
class PersonKeyframe:
    """The person's pose at time ``t``.

    Attributes:
        t: Time [s].
        position: Torso axis on the floor (x, y) in the base frame [m].
        yaw: Heading [rad] (0 = facing +x, π/2 = facing +y).
        right_hand: Right hand target (centre of the hand) in the base frame [m]; None = hanging.
        left_hand: Left hand target [m]; None = hanging.
    """

    t: float
    position: tuple[float, float]
    yaw: float = 0.0
    right_hand: tuple[float, float, float] | None = None
    left_hand: tuple[float, float, float] | None = None


@dataclass(frozen=True)
class PersonPose:
    """Interpolated pose at one instant.

    Attributes:
        position: Torso axis on the floor (x, y) [m].
        yaw: Heading [rad].
        hands: Hand targets [m] in the base frame, ``{"r": (3,), "l": (3,)}``.
    """

    position: tuple[float, float]
    yaw: float
    hands: dict[str, np.ndarray]


@dataclass(frozen=True)
class CapsuleEnds:
    """Every capsule of the person at several instants.

    Attributes:
        names: Geom names, in the order of the capsule axis (torso geoms, then each arm's segments).
        a: Segment starts [m]. Shape (T, G, 3).
        b: Segment ends [m] (= ``a`` for a sphere). Shape (T, G, 3).
        radius: Radii [m]. Shape (G,).
    """

    names: tuple[str, ...]
    a: np.ndarray
    b: np.ndarray
    radius: np.ndarray


@dataclass(frozen=True)
class _Body:
    geom_id: int
    mocap_id: int
    length_m: float  # capsule segment length (between the cap centres)
    radius_m: float


class Person:
    """Scripted person in a MuJoCo scene (see the module docstring for the rules).

    Args:
        model: Scene with the person's mocap bodies (``scene_workcell.xml``).
        keyframes: Poses with strictly increasing times; empty = nobody (parked far away).
        time_scale: Multiplies every keyframe time (``scenario.time_scale``).
        prefix: Prefix of the person's body, geom and site names.
        sample_period_s: The period at which :meth:`apply` is called (the control period) [s]:
            poses on that grid are computed in blocks ahead; other instants one at a time.
    """

    def __init__(
        self,
        model: mujoco.MjModel,
        keyframes: Sequence[KeyframeLike] = (),
        time_scale: float = 1.0,
        prefix: str = "person_",
        sample_period_s: float | None = None,
    ) -> None:
        if not time_scale > 0:
            raise SensingError(f"time_scale must be > 0, got {time_scale}")
        if sample_period_s is not None and not sample_period_s > 0:
            raise SensingError(f"sample_period_s must be > 0, got {sample_period_s}")
        self.model = model
        self.prefix = prefix
        self._torso = self._body(model, "torso")
        self._segments = {side: [self._body(model, f"{side}_{seg}") for seg in SEGMENTS] for side in SIDES}
        torso_body = model.body(prefix + "torso").id
        self._torso_geoms = [_torso_geom(model, int(g)) for g in np.flatnonzero(model.geom_bodyid == torso_body)]
        self._shoulders: dict[str, np.ndarray] = {}
        for side in SIDES:
            site = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, f"{prefix}{side}_shoulder")
            if site < 0 or model.site_bodyid[site] != torso_body:
                raise UnknownSceneElement("site", f"{prefix}{side}_shoulder", [])
            self._shoulders[side] = np.array(model.site_pos[site], dtype=float)
        floor = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, "floor")
        self.floor_z = float(model.geom_pos[floor][2]) if floor >= 0 else 0.0
        frames = list(keyframes)
        times = [float(f.t) * time_scale for f in frames]
        if any(b <= a for a, b in zip(times, times[1:], strict=False)):
            raise SensingError(f"person keyframe times must increase strictly, got {times}")
        for f in frames:
            if len(f.position) != 2 or not all(math.isfinite(v) for v in (*f.position, f.yaw)):
                raise SensingError(f"person keyframe at t={f.t}: position must be finite (x, y), yaw finite")
        # Per arm: upper arm L1, forearm + half hand L2, forearm, hand [m].
        self._lengths = {
            side: (up.length_m, fo.length_m + ha.length_m / 2.0, fo.length_m, ha.length_m)
            for side, (up, fo, ha) in self._segments.items()
        }
        ids = [self._torso.mocap_id] + [b.mocap_id for side in SIDES for b in self._segments[side]]
        contiguous = ids == list(range(ids[0], ids[0] + len(ids)))
        self._mocap_index: slice | list[int] = slice(ids[0], ids[0] + len(ids)) if contiguous else ids
        self.names: tuple[str, ...] = tuple(g[0] for g in self._torso_geoms) + tuple(
            model.geom(b.geom_id).name for side in SIDES for b in self._segments[side]
        )
        self._radius = np.array(
            [g[3] for g in self._torso_geoms] + [b.radius_m for s in SIDES for b in self._segments[s]]
        )
        self._times = np.array(times, dtype=float)
        parked = [self._resolve(PersonKeyframe(0.0, PARKED_POSITION))]
        self._keys = np.array([self._resolve(f) for f in frames] if frames else parked)
        # Yaw change of each keyframe segment along the shorter arc.
        self._dyaw = np.array(
            [math.remainder(b - a, math.tau) for a, b in zip(self._keys[:-1, _YAW], self._keys[1:, _YAW], strict=True)]
        )
        self._present = bool(frames)
        self._period = sample_period_s
        self._blocks: dict[int, tuple[np.ndarray, np.ndarray]] = {}

    def _body(self, model: mujoco.MjModel, name: str) -> _Body:
        full = self.prefix + name
        body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, full)
        if body < 0:
            names = [model.body(i).name for i in range(model.nbody) if model.body(i).name.startswith(self.prefix)]
            raise UnknownSceneElement("body", full, names)
        mocap = int(model.body_mocapid[body])
        if mocap < 0:
            raise SensingError(f"body '{full}' must be a mocap body")
        geom = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, full)
        if geom < 0:
            raise UnknownSceneElement("geom", full, [])
        radius, half = float(model.geom_size[geom][0]), float(model.geom_size[geom][1])
        return _Body(int(geom), mocap, 2.0 * half, radius)

    # -- keyframes --------------------------------------------------------------------------
    def _resolve(self, f: KeyframeLike) -> list[float]:
        """A keyframe as one key row (torso x, y, yaw, right hand, left hand), hand targets filled."""
        x, y, yaw = float(f.position[0]), float(f.position[1]), float(f.yaw)
        row = [x, y, yaw]
        for side, target in (("r", f.right_hand), ("l", f.left_hand)):
            if target is None:
                row.extend(self._hanging(x, y, yaw, side))
                continue
            vals = [float(v) for v in target]
            if len(vals) != 3 or not all(math.isfinite(v) for v in vals):
                raise SensingError(f"person keyframe at t={f.t}: hand target must be 3 finite numbers")
            row.extend(vals)
        return row

    @property
    def present(self) -> bool:
        """Whether the person has keyframes (otherwise it is parked out of sight)."""
        return self._present

    @property
    def times(self) -> list[float]:
        """Keyframe times after ``time_scale`` [s]."""
        return [float(t) for t in self._times]

    def _hanging(self, x: float, y: float, yaw: float, side: str) -> list[float]:
        mirror = 1.0 if side == "r" else -1.0
        reach = self._lengths[side][0] + self._lengths[side][1] - _HANG_SHORTFALL_M
        sx, sy, sz = self._shoulders[side]
        local = np.array([sx + _HANG_OFFSET[0], sy + mirror * _HANG_OFFSET[1], sz - reach])
        return [float(v) for v in self._to_world(np.array([x]), np.array([y]), np.array([yaw]), local)[0]]

    def _to_world(self, x: np.ndarray, y: np.ndarray, yaw: np.ndarray, local: np.ndarray) -> np.ndarray:
        """Torso-frame points ``local`` ((3,) or (T, 3)) in the base frame at each pose [m]. Shape (T, 3)."""
        c, s = np.cos(yaw), np.sin(yaw)
        lx, ly, lz = local[..., 0], local[..., 1], local[..., 2]
        return np.stack([x + c * lx - s * ly, y + s * lx + c * ly, self.floor_z + lz + 0.0 * x], axis=-1)

    def keys_at(self, times: np.ndarray | Sequence[float]) -> np.ndarray:
        """Interpolated key rows (torso x, y, yaw, right hand (3), left hand (3)) at ``times`` [s]. Shape (T, 9)."""
        t = np.asarray(times, dtype=float).reshape(-1)
        keys = self._keys
        n = len(keys)
        if n == 1:
            return np.repeat(keys, len(t), axis=0)
        k = np.searchsorted(self._times, t, side="right") - 1
        after = k >= n - 1
        seg = np.clip(k, 0, n - 2)
        t0, t1 = self._times[seg], self._times[seg + 1]
        alpha = np.where((k < 0) | after, 0.0, (t - t0) / (t1 - t0))
        delta = keys[seg + 1] - keys[seg]
        delta[:, _YAW] = self._dyaw[seg]
        base = np.where(after[:, None], keys[-1], keys[seg])
        return base + alpha[:, None] * delta

    def pose_at(self, t: float) -> PersonPose:
        """Interpolated pose at time ``t`` [s] (parked pose when there are no keyframes)."""
        key = self.keys_at([t])[0]
        return PersonPose(
            (float(key[_X]), float(key[_Y])), float(key[_YAW]), {"r": key[_RIGHT].copy(), "l": key[_LEFT].copy()}
        )

    # -- geometry ---------------------------------------------------------------------------
    def _arms(self, keys: np.ndarray) -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
        """Shoulder, elbow, wrist and fingertip of each arm for every key row (module docstring). Shapes (T, 3)."""
        x, y, yaw = keys[:, _X], keys[:, _Y], keys[:, _YAW]
        c, s = np.cos(yaw), np.sin(yaw)
        out = {}
        for side, cols in (("r", _RIGHT), ("l", _LEFT)):
            l1, l2, lf, lh = self._lengths[side]
            mirror = 1.0 if side == "r" else -1.0
            sh = self._to_world(x, y, yaw, self._shoulders[side])
            to = keys[:, cols] - sh
            dist = np.linalg.norm(to, axis=1)
            qx, qy, qz = _POLE_RIGHT[0], mirror * _POLE_RIGHT[1], _POLE_RIGHT[2]
            pole = np.stack([c * qx - s * qy, s * qx + c * qy, np.full_like(c, qz)], axis=1)
            along = np.where(
                (dist < 1e-9)[:, None],
                -pole / np.linalg.norm(pole, axis=1, keepdims=True),
                to / np.maximum(dist, 1e-300)[:, None],
            )
            d = np.clip(dist, abs(l1 - l2) + 1e-6, REACH_FRACTION * (l1 + l2))
            a = (l1 * l1 - l2 * l2 + d * d) / (2.0 * d)
            h = np.sqrt(np.maximum(l1 * l1 - a * a, 0.0))
            normal = pole - np.sum(pole * along, axis=1, keepdims=True) * along
            flat = np.linalg.norm(normal, axis=1) < 1e-9
            if np.any(flat):  # pole along the arm: bend sideways
                side_pole = np.stack([-s * mirror, c * mirror, np.zeros_like(c)], axis=1)
                sideways = side_pole - np.sum(side_pole * along, axis=1, keepdims=True) * along
                normal = np.where(flat[:, None], sideways, normal)
            normal /= np.linalg.norm(normal, axis=1, keepdims=True)
            elbow = sh + a[:, None] * along + h[:, None] * normal
            fore = sh + d[:, None] * along - elbow  # elbow -> hand centre
            fore /= np.linalg.norm(fore, axis=1, keepdims=True)
            wrist = elbow + lf * fore
            out[side] = (sh, elbow, wrist, wrist + lh * fore)
        return out

    def capsule_ends(self, times: np.ndarray | Sequence[float]) -> CapsuleEnds:
        """Every capsule at each of ``times`` [s], from the keyframes alone (no MuJoCo data)."""
        keys = self.keys_at(times)
        return self._capsules(keys, self._arms(keys))

    def _capsules(self, keys: np.ndarray, arms: dict[str, tuple[np.ndarray, ...]]) -> CapsuleEnds:
        x, y, yaw = keys[:, _X], keys[:, _Y], keys[:, _YAW]
        starts = [self._to_world(x, y, yaw, g[1]) for g in self._torso_geoms]
        ends = [self._to_world(x, y, yaw, g[2]) for g in self._torso_geoms]
        for side in SIDES:
            sh, elbow, wrist, tip = arms[side]
            starts += [sh, elbow, wrist]
            ends += [elbow, wrist, tip]
        return CapsuleEnds(self.names, np.stack(starts, axis=1), np.stack(ends, axis=1), self._radius.copy())

    def capsules_at(self, t: float) -> dict[str, tuple[np.ndarray, np.ndarray, float]]:
        """Every capsule of the person at time ``t``: geom name → (end A, end B, radius) [m].

        Computed from the keyframes alone, without MuJoCo data (a sphere has A = B).
        """
        caps = self.capsule_ends([t])
        return {n: (caps.a[0, g], caps.b[0, g], float(caps.radius[g])) for g, n in enumerate(caps.names)}

    # -- MuJoCo -----------------------------------------------------------------------------
    def mocap_poses(self, times: np.ndarray | Sequence[float]) -> tuple[np.ndarray, np.ndarray]:
        """Mocap positions (T, B, 3) [m] and quaternions (T, B, 4) of the person's bodies at ``times`` [s].

        Bodies in the order torso, then per arm upper arm, forearm, hand.
        """
        keys = self.keys_at(times)
        arms = self._arms(keys)
        yaw = keys[:, _YAW]
        pos = [np.stack([keys[:, _X], keys[:, _Y], np.full(len(keys), self.floor_z)], axis=1)]
        quat = [np.stack([np.cos(yaw / 2.0), 0.0 * yaw, 0.0 * yaw, np.sin(yaw / 2.0)], axis=1)]
        for side in SIDES:
            sh, elbow, wrist, tip = arms[side]
            fore = _quat_z_to(tip - elbow)
            pos += [sh, elbow, wrist]
            quat += [_quat_z_to(elbow - sh), fore, fore]
        return np.stack(pos, axis=1), np.stack(quat, axis=1)

    def _mocap_at(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        period = self._period
        if period is not None:
            k = round(t / period)
            if k >= 0 and abs(k * period - t) <= 1e-9 * max(1.0, abs(t)):
                block = k // _BLOCK
                if block not in self._blocks:
                    if len(self._blocks) > 8:
                        self._blocks.clear()
                    self._blocks[block] = self.mocap_poses((block * _BLOCK + np.arange(_BLOCK)) * period)
                pos, quat = self._blocks[block]
                return pos[k - block * _BLOCK], quat[k - block * _BLOCK]
        pos, quat = self.mocap_poses([t])
        return pos[0], quat[0]

    def apply(self, t: float, data: mujoco.MjData) -> None:
        """Write the mocap poses of time ``t`` [s] into ``data``.

        Call before ``mj_step`` (or follow with ``mj_kinematics``/``mj_forward``). Usable as the
        ``scene_update(t, data)`` callback of :class:`compare.loop.sim_io.SimRobotIO`.
        """
        pos, quat = self._mocap_at(t)
        data.mocap_pos[self._mocap_index] = pos
        data.mocap_quat[self._mocap_index] = quat

    __call__ = apply

    def __repr__(self) -> str:
        span = f"{self._times[0]:.1f}-{self._times[-1]:.1f} s" if self._present else "parked"
        return f"Person(keyframes={len(self._times)}, {span})"


def _torso_geom(model: mujoco.MjModel, geom: int) -> tuple[str, np.ndarray, np.ndarray, float]:
    """Name, segment ends in the torso frame [m] and radius of a geom of the torso body (a sphere: A = B)."""
    rot = np.empty(9)
    mujoco.mju_quat2Mat(rot, model.geom_quat[geom])
    is_capsule = model.geom_type[geom] == mujoco.mjtGeom.mjGEOM_CAPSULE
    half = float(model.geom_size[geom][1]) if is_capsule else 0.0
    axis = rot.reshape(3, 3)[:, 2] * half
    pos = np.array(model.geom_pos[geom], dtype=float)
    return model.geom(geom).name, pos - axis, pos + axis, float(model.geom_size[geom][0])


def _quat_z_to(v: np.ndarray) -> np.ndarray:
    """Unit quaternions (w, x, y, z), shape (T, 4), of the shortest rotations taking +z to each row of ``v`` (T, 3)."""
    n = np.linalg.norm(v, axis=1)
    u = v / np.maximum(n, 1e-300)[:, None]
    w = 1.0 + u[:, 2]
    q = np.stack([w, -u[:, 1], u[:, 0], np.zeros_like(w)], axis=1)
    q /= np.maximum(np.linalg.norm(q, axis=1), 1e-300)[:, None]
    q[w < 1e-9] = (0.0, 1.0, 0.0, 0.0)  # pointing straight down: half turn about x
    q[n < 1e-12] = (1.0, 0.0, 0.0, 0.0)
    return q

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
  :math:`D = \|T - S\|` clamped to :math:`[|L_1 - L_2|, L_1 + L_2]`,

  .. math::
      a = \frac{L_1^2 - L_2^2 + D^2}{2D},\quad h = \sqrt{L_1^2 - a^2},\quad
      E = S + a\,\hat e + h\,\hat n

  where :math:`\hat e` points from the shoulder to the target and :math:`\hat n` is the pole
  direction made orthogonal to it. An unreachable target is approached as far as the arm
  allows (the hand stops short on the shoulder–target line).

Segment lengths, radii and shoulder positions are read from the model (the MJCF is the single
source of truth). A person with no keyframes is parked far outside the camera's range.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import NamedTuple, Protocol

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

# Hanging arm, in the torso frame relative to the shoulder (x forward, y left, z up), before the
# side's mirroring in y: slightly forward and out, 3 cm short of full stretch.
_HANG_OFFSET = (0.05, -0.03)
_HANG_SHORTFALL_M = 0.03
# Elbow pole direction in the torso frame for the right arm (back, out, down); mirrored for the left.
_POLE_RIGHT = (-0.25, -0.5, -1.0)


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
    """

    def __init__(
        self,
        model: mujoco.MjModel,
        keyframes: Sequence[KeyframeLike] = (),
        time_scale: float = 1.0,
        prefix: str = "person_",
    ) -> None:
        if not time_scale > 0:
            raise SensingError(f"time_scale must be > 0, got {time_scale}")
        self.model = model
        self.prefix = prefix
        self._torso = self._body(model, "torso")
        self._segments = {side: [self._body(model, f"{side}_{seg}") for seg in SEGMENTS] for side in SIDES}
        torso_body = model.body(prefix + "torso").id
        self._torso_geoms = [int(g) for g in np.flatnonzero(model.geom_bodyid == torso_body)]
        self._shoulders: dict[str, _Vec] = {}
        for side in SIDES:
            site = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, f"{prefix}{side}_shoulder")
            if site < 0 or model.site_bodyid[site] != torso_body:
                raise UnknownSceneElement("site", f"{prefix}{side}_shoulder", [])
            sx, sy, sz = (float(v) for v in model.site_pos[site])
            self._shoulders[side] = (sx, sy, sz)
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
        self._times = times
        self._keys = [self._resolve(f) for f in frames]
        self._stationary = [a == b for a, b in zip(self._keys, self._keys[1:], strict=False)]
        self._cache_key: tuple[int, int, tuple[float, ...]] | None = None

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
    def _resolve(self, f: KeyframeLike) -> _Key:
        x, y, yaw = float(f.position[0]), float(f.position[1]), float(f.yaw)
        hands = []
        for side, target in (("r", f.right_hand), ("l", f.left_hand)):
            if target is None:
                hands.append(self._hanging(x, y, yaw, side))
            else:
                vals = tuple(float(v) for v in target)
                if len(vals) != 3 or not all(math.isfinite(v) for v in vals):
                    raise SensingError(f"person keyframe at t={f.t}: hand target must be 3 finite numbers")
                hands.append(vals)
        return _Key(x, y, yaw, hands[0], hands[1])

    @property
    def present(self) -> bool:
        """Whether the person has keyframes (otherwise it is parked out of sight)."""
        return bool(self._keys)

    @property
    def times(self) -> list[float]:
        """Keyframe times after ``time_scale`` [s]."""
        return list(self._times)

    def hanging_hand(self, position: tuple[float, float], yaw: float, side: str) -> np.ndarray:
        """Hand centre of a relaxed arm for a torso at ``position`` with heading ``yaw`` [m]."""
        return np.array(self._hanging(float(position[0]), float(position[1]), float(yaw), side))

    def _hanging(self, x: float, y: float, yaw: float, side: str) -> _Vec:
        mirror = 1.0 if side == "r" else -1.0
        reach = self._lengths[side][0] + self._lengths[side][1] - _HANG_SHORTFALL_M
        sx, sy, sz = self._shoulders[side]
        return self._to_world(x, y, yaw, (sx + _HANG_OFFSET[0], sy + mirror * _HANG_OFFSET[1], sz - reach))

    def _to_world(self, x: float, y: float, yaw: float, local: _Vec) -> _Vec:
        c, s = math.cos(yaw), math.sin(yaw)
        return (x + c * local[0] - s * local[1], y + s * local[0] + c * local[1], self.floor_z + local[2])

    def _segment(self, t: float) -> tuple[int, float]:
        """Keyframe index k and weight α of ``t``: pose = (1-α) pose_k + α pose_{k+1}."""
        k = bisect.bisect_right(self._times, t) - 1
        if k < 0:
            return 0, 0.0
        if k >= len(self._times) - 1:
            return len(self._times) - 1, 0.0
        t0, t1 = self._times[k], self._times[k + 1]
        return k, (t - t0) / (t1 - t0)

    def _key_at(self, t: float) -> _Key:
        if not self._keys:
            x, y = PARKED_POSITION
            return _Key(x, y, 0.0, self._hanging(x, y, 0.0, "r"), self._hanging(x, y, 0.0, "l"))
        k, alpha = self._segment(t)
        a = self._keys[k]
        if alpha == 0.0:
            return a
        b = self._keys[k + 1]
        dyaw = math.remainder(b.yaw - a.yaw, math.tau)
        return _Key(
            a.x + alpha * (b.x - a.x),
            a.y + alpha * (b.y - a.y),
            a.yaw + alpha * dyaw,
            _lerp(a.right, b.right, alpha),
            _lerp(a.left, b.left, alpha),
        )

    def pose_at(self, t: float) -> PersonPose:
        """Interpolated pose at time ``t`` [s] (parked pose when there are no keyframes)."""
        key = self._key_at(t)
        return PersonPose((key.x, key.y), key.yaw, {"r": np.array(key.right), "l": np.array(key.left)})

    # -- geometry ---------------------------------------------------------------------------
    def arm_points(self, t: float, side: str) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Shoulder, elbow, wrist and hand end of arm ``side`` (``"r"``/``"l"``) at time ``t`` [m]."""
        key = self._key_at(t)
        pts = self._arm(key, side)
        return np.array(pts[0]), np.array(pts[1]), np.array(pts[2]), np.array(pts[3])

    def _arm(self, key: _Key, side: str) -> tuple[_Vec, _Vec, _Vec, _Vec]:
        """Two-link IK of one arm (module docstring), in plain floats: this runs every physics step."""
        l1, l2, lf, lh = self._lengths[side]
        yaw = key.yaw
        sh = self._to_world(key.x, key.y, yaw, self._shoulders[side])
        target = key.right if side == "r" else key.left
        tx, ty, tz = target[0] - sh[0], target[1] - sh[1], target[2] - sh[2]
        dist = math.sqrt(tx * tx + ty * ty + tz * tz)
        c, s = math.cos(yaw), math.sin(yaw)
        mirror = 1.0 if side == "r" else -1.0
        qx, qy, qz = _POLE_RIGHT[0], mirror * _POLE_RIGHT[1], _POLE_RIGHT[2]
        px, py, pz = c * qx - s * qy, s * qx + c * qy, qz
        if dist < 1e-9:
            pn = math.sqrt(px * px + py * py + pz * pz)
            ex, ey, ez = -px / pn, -py / pn, -pz / pn
        else:
            ex, ey, ez = tx / dist, ty / dist, tz / dist
        d = min(max(dist, abs(l1 - l2) + 1e-6), l1 + l2)
        a = (l1 * l1 - l2 * l2 + d * d) / (2.0 * d)
        h = math.sqrt(max(l1 * l1 - a * a, 0.0))
        dot = px * ex + py * ey + pz * ez
        nx, ny, nz = px - dot * ex, py - dot * ey, pz - dot * ez
        nn = math.sqrt(nx * nx + ny * ny + nz * nz)
        if nn < 1e-9:  # pole along the arm: bend sideways
            px, py, pz = -s * mirror, c * mirror, 0.0
            dot = px * ex + py * ey
            nx, ny, nz = px - dot * ex, py - dot * ey, -dot * ez
            nn = math.sqrt(nx * nx + ny * ny + nz * nz)
        nx, ny, nz = nx / nn, ny / nn, nz / nn
        elbow = (sh[0] + a * ex + h * nx, sh[1] + a * ey + h * ny, sh[2] + a * ez + h * nz)
        # Forearm direction: elbow -> hand centre (shoulder + d e).
        fx, fy, fz = sh[0] + d * ex - elbow[0], sh[1] + d * ey - elbow[1], sh[2] + d * ez - elbow[2]
        fn = math.sqrt(fx * fx + fy * fy + fz * fz)
        fx, fy, fz = fx / fn, fy / fn, fz / fn
        wrist = (elbow[0] + lf * fx, elbow[1] + lf * fy, elbow[2] + lf * fz)
        tip = (wrist[0] + lh * fx, wrist[1] + lh * fy, wrist[2] + lh * fz)
        return sh, elbow, wrist, tip

    def capsules_at(self, t: float) -> dict[str, tuple[np.ndarray, np.ndarray, float]]:
        """Every capsule of the person at time ``t``: geom name → (end A, end B, radius) [m].

        Computed from the keyframes alone, without MuJoCo data (a sphere has A = B).
        """
        key = self._key_at(t)
        out: dict[str, tuple[np.ndarray, np.ndarray, float]] = {}
        model = self.model
        for geom in self._torso_geoms:
            rot = np.empty(9)
            mujoco.mju_quat2Mat(rot, model.geom_quat[geom])
            is_capsule = model.geom_type[geom] == mujoco.mjtGeom.mjGEOM_CAPSULE
            half = float(model.geom_size[geom][1]) if is_capsule else 0.0
            axis = rot.reshape(3, 3)[:, 2] * half
            pos = model.geom_pos[geom]
            out[model.geom(geom).name] = (
                np.array(self._to_world(key.x, key.y, key.yaw, tuple(pos - axis))),
                np.array(self._to_world(key.x, key.y, key.yaw, tuple(pos + axis))),
                float(model.geom_size[geom][0]),
            )
        for side in SIDES:
            shoulder, elbow, wrist, tip = self._arm(key, side)
            ends = ((shoulder, elbow), (elbow, wrist), (wrist, tip))
            for body, (a, b) in zip(self._segments[side], ends, strict=True):
                out[model.geom(body.geom_id).name] = (np.array(a), np.array(b), body.radius_m)
        return out

    # -- MuJoCo -----------------------------------------------------------------------------
    def apply(self, t: float, data: mujoco.MjData) -> None:
        """Write the mocap poses of time ``t`` [s] into ``data``.

        Call before ``mj_step`` (or follow with ``mj_kinematics``/``mj_forward``). Cheap: a
        pose already written while the person stands still is not rewritten, and a moving
        pose costs ~20 µs. Usable as the ``scene_update(t, data)`` callback of
        :class:`compare.loop.sim_io.SimRobotIO`.
        """
        if self._keys:
            k, alpha = self._segment(t)
            still = alpha == 0.0 or self._stationary[k]
        else:
            k, still = -1, True
        torso = self._torso.mocap_id
        if still and self._cache_key == (k, id(data), tuple(data.mocap_pos[torso])):
            return
        key = self._key_at(t)
        pos = [(key.x, key.y, self.floor_z)]
        quat = [(math.cos(key.yaw / 2.0), 0.0, 0.0, math.sin(key.yaw / 2.0))]
        for side in SIDES:
            shoulder, elbow, wrist, tip = self._arm(key, side)
            upper = _quat_z_to(elbow[0] - shoulder[0], elbow[1] - shoulder[1], elbow[2] - shoulder[2])
            fore = _quat_z_to(tip[0] - elbow[0], tip[1] - elbow[1], tip[2] - elbow[2])
            pos += [shoulder, elbow, wrist]
            quat += [upper, fore, fore]
        data.mocap_pos[self._mocap_index] = np.array(pos)
        data.mocap_quat[self._mocap_index] = np.array(quat)
        self._cache_key = (k, id(data), tuple(data.mocap_pos[torso])) if still else None

    __call__ = apply

    def hide(self, data: mujoco.MjData) -> None:
        """Park the person out of sight in ``data`` (whatever its keyframes)."""
        saved = self._keys
        self._keys = []
        self._cache_key = None
        try:
            self.apply(0.0, data)
        finally:
            self._keys = saved
            self._cache_key = None

    def __repr__(self) -> str:
        span = f"{self._times[0]:.1f}-{self._times[-1]:.1f} s" if self._times else "parked"
        return f"Person(keyframes={len(self._times)}, {span})"


class _Key(NamedTuple):
    """A keyframe resolved to floats (hand targets always set)."""

    x: float
    y: float
    yaw: float
    right: _Vec
    left: _Vec


def _lerp(a: _Vec, b: _Vec, alpha: float) -> _Vec:
    return (a[0] + alpha * (b[0] - a[0]), a[1] + alpha * (b[1] - a[1]), a[2] + alpha * (b[2] - a[2]))


def _quat_z_to(dx: float, dy: float, dz: float) -> tuple[float, float, float, float]:
    """Unit quaternion (w, x, y, z) of the shortest rotation taking +z to the direction (dx, dy, dz)."""
    n = math.sqrt(dx * dx + dy * dy + dz * dz)
    if n < 1e-12:
        return (1.0, 0.0, 0.0, 0.0)
    ux, uy, uz = dx / n, dy / n, dz / n
    w = 1.0 + uz
    if w < 1e-9:  # pointing straight down: half turn about x
        return (0.0, 1.0, 0.0, 0.0)
    qn = math.sqrt(w * w + uy * uy + ux * ux)
    return (w / qn, -uy / qn, ux / qn, 0.0)

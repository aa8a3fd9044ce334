"""Checks of every message the bridge reads, before any value reaches the controller (no ROS import).

Each check either returns the message's values in the project's units or raises
:class:`MalformedMessage` with a short ``kind`` (counted per topic in ``summary.json``,
``hardware.ignored_message_causes``) and a one-line detail. A malformed message is dropped:
the controller keeps the last good value, and when good messages stop coming the watchdog
zeroes the velocity and stops the driver (stale data). A message from a second publisher is
dropped *and* halts the arm (:class:`SenderCheck`).

* :class:`StampCheck` — per topic: header stamps advance (never backwards, never repeated), and
  by no more than :data:`STAMP_JUMP_S` beyond what the arrivals advanced; a stream that was
  stamped stays stamped. After a dropped jump the stream stays dropped until it agrees again
  with the last accepted stamp (a publisher's clock stepped forward means a restart).
* :class:`JointStateCheck` — names unique, the same names in the same order as the first
  accepted state, the wanted joints present, one position per name (velocities: none or one
  per name), finite, within :data:`MAX_ABS_JOINT_RAD`.
* :class:`CameraInfoCheck` — a pinhole ``K`` (finite, fx, fy > 0, last row 0 0 1, principal point
  inside the image), a plausible size, and no change of size, ``K`` or frame after the first.
* :class:`DepthCheck` — the camera info's size and frame, a known encoding, ``is_bigendian`` 0 or
  1, ``step`` ≥ one row, exactly ``step × height`` bytes. Non-finite and non-positive depths are
  "no return" (0), as ``sensor_msgs/Image`` depth images encode them.
* :func:`check_service_answer` — the driver's ``in/stop``/``in/start`` answer is its response type
  with a text result.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

from compare.hardware.conversions import DEPTH_ENCODINGS, decode_depth, joint_indices
from compare.hardware.exceptions import HardwareError
from compare.hardware.publisher_watch import second_publisher_cause
from compare.sensing.frames import CameraModel

STAMP_JUMP_S = 0.5
"""Largest advance of a header stamp beyond the advance of the arrivals [s]."""
MAX_ABS_JOINT_RAD = 1000.0
"""Largest plausible joint position [rad]: the driver's angles are not wrapped, but a few turns at most."""
MAX_IMAGE_SIDE_PX = 8192
"""Largest image width or height accepted [px]."""


class MalformedMessage(HardwareError):
    """A message the bridge read breaks its contract; it is dropped.

    Args:
        kind: Short cause, the key counted in the report (``"stamp backwards"``).
        detail: What exactly was wrong (logged).
    """

    def __init__(self, kind: str, detail: str) -> None:
        super().__init__(f"{kind}: {detail}")
        self.kind = kind


def header_stamp_s(msg: Any) -> float:
    """The header stamp of a message [s] (0 when unset).

    Raises:
        MalformedMessage: no header stamp.
    """
    stamp = getattr(getattr(msg, "header", None), "stamp", None)
    if stamp is None:
        raise MalformedMessage("no header", f"{type(msg).__name__} has no header stamp")
    try:
        return float(stamp.to_sec())
    except (AttributeError, TypeError, ValueError) as exc:
        raise MalformedMessage("bad stamp", str(exc)) from None


def _finite_floats(values: Any, what: str) -> np.ndarray:
    try:
        out = np.asarray(values, dtype=float)
    except (TypeError, ValueError) as exc:
        raise MalformedMessage(f"{what} not numbers", str(exc)) from None
    if out.ndim != 1:
        raise MalformedMessage(f"{what} not a list", f"shape {out.shape}")
    return out


class StampCheck:
    """Header stamps of one topic: advancing, no jump ahead of the arrivals, stamped or not throughout.

    Args:
        jump_s: Largest advance of the stamp beyond the advance of the arrivals [s].
    """

    def __init__(self, jump_s: float = STAMP_JUMP_S) -> None:
        self.jump_s = float(jump_s)
        self._last: tuple[float, float] | None = None  # (stamp, arrival) of the last accepted message

    def check(self, stamp_s: float, arrival_s: float) -> None:
        """Raise if ``stamp_s`` [s] may not follow the last accepted one (arrived at ``arrival_s`` [s])."""
        if not math.isfinite(stamp_s) or stamp_s < 0.0:
            raise MalformedMessage("bad stamp", f"{stamp_s}")
        if self._last is None:
            return
        last_stamp, last_arrival = self._last
        if last_stamp > 0.0 and stamp_s == 0.0:
            raise MalformedMessage("stamp missing", "the stream was stamped until now")
        if last_stamp == 0.0:
            return  # an unstamped stream (stamps all 0) may start stamping
        if stamp_s < last_stamp:
            raise MalformedMessage("stamp backwards", f"{1e3 * (last_stamp - stamp_s):.1f} ms before the last one")
        if stamp_s == last_stamp:
            raise MalformedMessage("stamp repeated", f"{stamp_s:.9f} s again")
        ahead = (stamp_s - last_stamp) - (arrival_s - last_arrival)
        if ahead > self.jump_s:
            raise MalformedMessage(
                "stamp jump",
                f"{stamp_s - last_stamp:.3f} s after the last one, "
                f"which arrived {arrival_s - last_arrival:.3f} s before this one",
            )

    def accept(self, stamp_s: float, arrival_s: float) -> None:
        """Record an accepted message."""
        self._last = (stamp_s, arrival_s)


class SenderCheck:
    """Messages of one topic come from one publisher: the first seen, by caller id.

    rospy puts the connection header (with the publisher's ``callerid``) on every message it
    delivers; a message without one (a replayed or hand-made message) is not judged.

    Args:
        topic: The topic (for the cause).
    """

    def __init__(self, topic: str) -> None:
        self.topic = topic
        self.caller_id: str | None = None

    def cause(self, msg: Any) -> str | None:
        """The halt cause when ``msg`` comes from another publisher than the first, else None."""
        header = getattr(msg, "_connection_header", None)
        caller = header.get("callerid") if isinstance(header, Mapping) else None
        if not isinstance(caller, str):
            return None
        if self.caller_id is None:
            self.caller_id = caller
            return None
        return None if caller == self.caller_id else second_publisher_cause(caller, self.topic)


class JointStateCheck:
    """``sensor_msgs/JointState`` → the arm's positions and velocities, in model order.

    Args:
        wanted: The arm's joint names in model order (``hardware.joint_names``).
        stamps: Stamp check of the topic.
    """

    def __init__(self, wanted: Sequence[str], stamps: StampCheck | None = None) -> None:
        self.wanted = tuple(wanted)
        self.stamps = stamps or StampCheck()
        self.names: tuple[str, ...] | None = None
        self._indices: np.ndarray | None = None

    def parse(
        self, names: Sequence[Any], position: Any, velocity: Any, stamp_s: float, arrival_s: float
    ) -> tuple[np.ndarray, np.ndarray]:
        """Positions [rad] and velocities [rad/s] of the wanted joints. Shapes (n,), (n,).

        Raises:
            MalformedMessage: the message breaks the contract of the module docstring.
        """
        names = tuple(names)
        if not all(isinstance(n, str) for n in names):
            raise MalformedMessage("names not text", f"{list(names)!r}")
        if len(set(names)) != len(names):
            raise MalformedMessage("duplicate names", f"{list(names)}")
        if self.names is None:
            try:
                indices = joint_indices(names, self.wanted)
            except HardwareError as exc:
                raise MalformedMessage("joints missing", str(exc)) from None
        elif names != self.names:
            raise MalformedMessage("names changed", f"{list(names)}, the first joint state had {list(self.names)}")
        else:
            indices = self._indices  # type: ignore[assignment]
        pos = _finite_floats(position, "positions")
        if pos.size != len(names):
            raise MalformedMessage("positions size", f"{pos.size} positions for {len(names)} names")
        q = pos[indices]
        if not np.all(np.isfinite(q)):
            raise MalformedMessage("position not finite", f"{q.tolist()}")
        if np.any(np.abs(q) > MAX_ABS_JOINT_RAD):
            raise MalformedMessage("position implausible", f"|q| > {MAX_ABS_JOINT_RAD:g} rad: {q.tolist()}")
        vel = _finite_floats(velocity, "velocities")
        if vel.size not in (0, len(names)):
            raise MalformedMessage("velocities size", f"{vel.size} velocities for {len(names)} names")
        qdot = vel[indices] if vel.size else np.zeros(len(self.wanted))
        if not np.all(np.isfinite(qdot)):
            raise MalformedMessage("velocity not finite", f"{qdot.tolist()}")
        self.stamps.check(stamp_s, arrival_s)
        self.stamps.accept(stamp_s, arrival_s)
        self.names, self._indices = names, indices
        return q, qdot


class CameraInfoCheck:
    """``sensor_msgs/CameraInfo`` → the camera model; the first accepted one is kept for the run.

    Args:
        make_camera: Builds the model from (width, height, K) (the calibrated pose and ranges are its own).
        stamps: Stamp check of the topic.
    """

    def __init__(
        self, make_camera: Callable[[int, int, Sequence[float]], CameraModel], stamps: StampCheck | None = None
    ) -> None:
        self._make_camera = make_camera
        self.stamps = stamps or StampCheck()
        self.camera: CameraModel | None = None
        self.frame_id: str | None = None
        self._fixed: tuple[int, int, tuple[float, ...], str] | None = None

    def parse(self, width: int, height: int, K: Any, frame_id: str, stamp_s: float, arrival_s: float) -> CameraModel:
        """The camera model of this camera info (the same object as long as nothing changes).

        Raises:
            MalformedMessage: the message breaks the contract of the module docstring.
        """
        if not (0 < width <= MAX_IMAGE_SIDE_PX and 0 < height <= MAX_IMAGE_SIDE_PX):
            raise MalformedMessage("image size", f"{width}x{height} (each side 1..{MAX_IMAGE_SIDE_PX} px)")
        k = _finite_floats(K, "K")
        if k.size != 9 or not np.all(np.isfinite(k)):
            raise MalformedMessage("K not finite", f"{k.tolist()}")
        if k[0] <= 0.0 or k[4] <= 0.0 or k[3] != 0.0 or k[6] != 0.0 or k[7] != 0.0 or k[8] != 1.0:
            raise MalformedMessage("K not pinhole", f"{k.tolist()} (fx, fy > 0, row 2 = 0 fy cy, row 3 = 0 0 1)")
        if not (0.0 <= k[2] < width and 0.0 <= k[5] < height):
            raise MalformedMessage("principal point", f"({k[2]:g}, {k[5]:g}) outside the {width}x{height} image")
        fixed = (int(width), int(height), tuple(float(v) for v in k), str(frame_id))
        if self._fixed is not None and fixed != self._fixed:
            raise MalformedMessage("camera_info changed", f"{fixed} after {self._fixed}")
        self.stamps.check(stamp_s, arrival_s)
        if self.camera is None:
            try:
                self.camera = self._make_camera(fixed[0], fixed[1], fixed[2])
            except HardwareError as exc:
                raise MalformedMessage("camera_info", str(exc)) from None
            self._fixed, self.frame_id = fixed, fixed[3]
        self.stamps.accept(stamp_s, arrival_s)
        return self.camera


class DepthCheck:
    """``sensor_msgs/Image`` depth → depth [m] for the accepted camera.

    Args:
        stamps: Stamp check of the topic.
    """

    def __init__(self, stamps: StampCheck | None = None) -> None:
        self.stamps = stamps or StampCheck()

    def parse(
        self,
        camera: CameraModel,
        camera_frame_id: str | None,
        msg: Any,
        stamp_s: float,
        arrival_s: float,
    ) -> np.ndarray:
        """Depth [m], float32, shape (height, width); 0 = no return.

        Args:
            camera: The accepted camera model.
            camera_frame_id: The camera info's frame (None: not checked).
            msg: The image (``encoding``, ``height``, ``width``, ``step``, ``is_bigendian``, ``data``,
                ``header.frame_id``).
            stamp_s: Its header stamp [s].
            arrival_s: Its arrival [s].

        Raises:
            MalformedMessage: the message breaks the contract of the module docstring.
        """
        width, height, step = int(msg.width), int(msg.height), int(msg.step)
        if (width, height) != (camera.width, camera.height):
            raise MalformedMessage("image size", f"{width}x{height} but camera_info {camera.width}x{camera.height}")
        if camera_frame_id is not None and msg.header.frame_id != camera_frame_id:
            raise MalformedMessage("frame", f"'{msg.header.frame_id}' but camera_info '{camera_frame_id}'")
        if msg.encoding not in DEPTH_ENCODINGS:
            raise MalformedMessage("encoding", f"'{msg.encoding}' (expected one of {DEPTH_ENCODINGS})")
        if msg.is_bigendian not in (0, 1):
            raise MalformedMessage("is_bigendian", f"{msg.is_bigendian} (0 or 1)")
        pixel_bytes = 4 if msg.encoding == "32FC1" else 2
        data = msg.data
        if step < width * pixel_bytes or len(data) != step * height:
            raise MalformedMessage(
                "data size", f"{len(data)} bytes, step {step}: expected step ≥ {width * pixel_bytes}, step × {height}"
            )
        self.stamps.check(stamp_s, arrival_s)
        try:
            depth = decode_depth(msg.encoding, height, width, step, bool(msg.is_bigendian), data)
        except HardwareError as exc:  # pragma: no cover - the checks above leave nothing to refuse
            raise MalformedMessage("depth", str(exc)) from None
        self.stamps.accept(stamp_s, arrival_s)
        return depth


def check_service_answer(service: str, answer: Any, response_class: Any, field: str) -> str:
    """The text result of a driver service's answer.

    Raises:
        HardwareError: the answer is not ``response_class`` or its ``field`` is not text.
    """
    if response_class is not None and not isinstance(answer, response_class):
        raise HardwareError(f"{service} answered {type(answer).__name__}, not {getattr(response_class, '_type', '?')}")
    result = getattr(answer, field, None)
    if not isinstance(result, str):
        raise HardwareError(f"{service} answered {field} = {result!r}, not text")
    return result

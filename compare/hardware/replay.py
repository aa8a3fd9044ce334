"""Recorded joint-state and depth streams, played into the bridge without an arm (``tpik-compare hw --replay``).

A recording is a ROS 1 bag (``rosbag record`` on the real setup, or the stand-in's
``--record-bag``) holding ``hardware.joint_state_topic``, ``hardware.depth_topic`` and
``hardware.camera_info_topic``; a directory stands for the ``.bag`` files in it, in name order
(``rosbag record --split`` writes several). Messages are fed to the bridge's own callbacks
(:class:`~compare.hardware.ros_io.RosRobotIO`) at their recorded times, paced in real time:
decoding, rates, gaps, the start checks (state rate and gaps, safety thresholds, calibration
residual), the self-filter, the static background, the distances and the watchdog all run as
on the arm. Nothing is published and no driver service is called; the commands the controller
would have sent are in the per-step table, but the recorded arm does not follow them (it moved
as it did during the recording).

Reading bags needs Debian's ``python3-rosbag`` (``make hw-deps``), not a ROS master.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from compare.hardware.exceptions import HardwareError
from compare.hardware.ros_env import load_ros

log = logging.getLogger(__name__)


class ReplayError(HardwareError):
    """The recording cannot be read or lacks a topic."""


def bag_files(path: Path) -> list[Path]:
    """The bags of ``path`` (a ``.bag`` file, or a directory of them in name order).

    Raises:
        ReplayError: nothing to read.
    """
    path = Path(path)
    if path.is_dir():
        bags = sorted(path.glob("*.bag"))
        if not bags:
            raise ReplayError(f"replay: no .bag file in {path}")
        return bags
    if not path.is_file():
        raise ReplayError(f"replay: {path} does not exist")
    return [path]


@dataclass
class Recording:
    """An opened recording.

    Attributes:
        bags: The bag files.
        topics: Topic → message type, over all bags.
        start_s: Time of the first message [s] (the recorder's clock).
        end_s: Time of the last message [s].
    """

    bags: list[Path]
    topics: dict[str, str]
    start_s: float
    end_s: float

    @property
    def duration_s(self) -> float:
        """Length of the recording [s]."""
        return self.end_s - self.start_s

    def require(self, *topics: str) -> None:
        """Raise :class:`ReplayError` naming the missing topics and those present."""
        missing = [t for t in topics if t not in self.topics]
        if missing:
            raise ReplayError(
                f"replay: {', '.join(missing)} not in {', '.join(str(b) for b in self.bags)} "
                f"(it has {sorted(self.topics)}; check the [hardware] topics)"
            )

    def messages(self, topics: list[str]) -> Iterator[tuple[str, Any, float]]:
        """(topic, message, time [s]) of ``topics``, in time order, bag after bag."""
        rosbag = _rosbag()
        for path in self.bags:
            with rosbag.Bag(str(path)) as bag:
                for topic, msg, t in bag.read_messages(topics=topics):
                    yield topic, msg, t.to_sec()


def _rosbag() -> Any:
    load_ros()  # makes Debian's ROS packages importable (rosbag among them)
    try:
        import rosbag  # Deferred: ROS 1 is optional, importable only after load_ros()
    except ImportError as exc:
        raise ReplayError(f"replay needs rosbag ({exc}): run `make hw-deps`") from exc
    return rosbag


def open_recording(path: Path) -> Recording:
    """Open a bag or a directory of bags.

    Raises:
        ReplayError: missing file, unreadable bag, or an empty recording.
    """
    rosbag = _rosbag()
    bags = bag_files(path)
    topics: dict[str, str] = {}
    start, end = float("inf"), float("-inf")
    for b in bags:
        try:
            with rosbag.Bag(str(b)) as bag:
                info = bag.get_type_and_topic_info()
                for topic, entry in info.topics.items():
                    topics[topic] = entry.msg_type
                if bag.get_message_count() > 0:
                    start, end = min(start, bag.get_start_time()), max(end, bag.get_end_time())
        except (rosbag.ROSBagException, OSError) as exc:
            raise ReplayError(f"replay: cannot read {b}: {exc}") from None
    if not topics or start > end:
        raise ReplayError(f"replay: {path} holds no messages")
    return Recording(bags, topics, start, end)


class ReplayFeeder:
    """Plays a recording into callbacks at its recorded pace, on a thread.

    Args:
        recording: What to play.
        callbacks: Topic → callback taking the message (the bridge's subscriber callbacks).
        speed: Playback speed (1 = as recorded).
    """

    def __init__(self, recording: Recording, callbacks: dict[str, Callable[[Any], None]], speed: float = 1.0) -> None:
        self.recording = recording
        self.callbacks = callbacks
        self.speed = float(speed)
        self.started_wall: float | None = None
        self.finished = threading.Event()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.count = 0

    def start(self) -> None:
        """Start playing."""
        self._thread = threading.Thread(target=self._run, name="tpik-hw-replay", daemon=True)
        self._thread.start()

    def remaining_s(self) -> float:
        """Recorded time left to play [s] (wall-clock seconds at speed 1)."""
        if self.started_wall is None:
            return self.recording.duration_s / self.speed
        return max(0.0, self.recording.duration_s / self.speed - (time.monotonic() - self.started_wall))

    def stop(self) -> None:
        """Stop playing (idempotent)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)

    def _run(self) -> None:
        t0 = self.recording.start_s
        self.started_wall = wall0 = time.monotonic()
        try:
            for topic, msg, t in self.recording.messages(list(self.callbacks)):
                due = wall0 + (t - t0) / self.speed
                while not self._stop.is_set():
                    delay = due - time.monotonic()
                    if delay <= 0:
                        break
                    self._stop.wait(min(delay, 0.05))
                if self._stop.is_set():
                    return
                self.callbacks[topic](msg)
                self.count += 1
        finally:
            self.finished.set()
            log.info("replay: %d messages played", self.count)

"""ROS 1 implementation of :class:`~compare.loop.robot_io.RobotIO`: the kinova-ros driver and a depth camera.

Data flow (one process; rospy's receive threads fill the latest values, the control loop reads them):

* ``hardware.joint_state_topic`` (``sensor_msgs/JointState``, rad) → :meth:`RosRobotIO.read_joints`;
  the 7 arm joints are picked by name, fingers are ignored;
* ``hardware.depth_topic`` + ``hardware.camera_info_topic`` → :meth:`RosRobotIO.read_depth`, a
  :class:`~compare.loop.robot_io.DepthFrame` with the calibrated camera pose from the config;
* :meth:`RosRobotIO.send_velocity` [rad/s] holds the command; the *command stream* thread
  publishes it on ``hardware.velocity_topic`` (``kinova_msgs/JointVelocity``, **deg/s**) on a
  fixed 100 Hz schedule, through the clamps and the :class:`~compare.hardware.safety.Watchdog`.

The stream thread is the loop's clock (:meth:`RosRobotIO.wait` returns at its ticks), so one
message leaves every 10 ms (faster would fill the arm's trajectory FIFO and the arm would keep
moving after the stream stops; slower starves it), the held command is re-sent if the loop misses
a tick, zero goes out when the loop stalls for 3 periods, and zero goes out *at once* (not at the
next tick) when joint state or depth goes stale while the arm moves. One message per 10 ms
*sent* is not one per 10 ms *executed*: the driver's single spin thread is busy with its status
timer and its subscription queue holds one message, so over USB about half of the commands are
dropped (docs/hardware.md, "What reaches the arm"; ``compare.hardware.driver_model``).

Every halt path (Ctrl-C, errors, a watchdog trip, the end of the run) also calls the driver's
``in/stop``, which erases the points still queued in the arm; ``in/start`` is called before the
run and after a watchdog trip once the data is fresh again
(:class:`~compare.hardware.driver_control.DriverControl`).

Times are on this process's monotonic clock, in seconds since :meth:`RosRobotIO.start_clock`
(arrival times, not the senders' header stamps: machines' clocks may differ).
"""

from __future__ import annotations

import logging
import math
import os
import socket
import sys
import threading
import time
from collections import deque
from typing import Any

import numpy as np

from compare.config import HardwareConfig
from compare.hardware.conversions import (
    camera_model_from_info,
    rad_s_to_deg_s,
    transform_from_translation_quaternion,
)
from compare.hardware.driver_control import DriverControl, DriverServiceError
from compare.hardware.exceptions import HardwareError, MasterUnreachable, StartRefused
from compare.hardware.exposure import ExposureReport, NetworkExposed, check_exposure, exposed_own_sockets
from compare.hardware.master_api import master_online, topic_publishers
from compare.hardware.publisher_watch import PublisherWatch
from compare.hardware.replay import Recording, ReplayFeeder
from compare.hardware.ros_env import RosApi, load_ros
from compare.hardware.safety import NO_COMMAND_YET, CommandLimiter, Watchdog, WatchdogEvent
from compare.hardware.validation import (
    CameraInfoCheck,
    DepthCheck,
    JointStateCheck,
    MalformedMessage,
    SenderCheck,
    check_service_answer,
    header_stamp_s,
)
from compare.loop.robot_io import JointReading, RobotIO
from compare.sensing.frames import CameraModel, DepthFrame

log = logging.getLogger(__name__)

_STOP_REPEAT_S = 0.1
"""How long zero velocity is streamed when stopping [s] (the driver stops when the stream ends)."""


__all__ = ["RosRobotIO", "init_node", "master_online", "stamp_on_this_clock"]

MASTER_SILENCE_MIN_S = 1.0
"""The publisher watch halts when the master has not answered for max(this, the joint-state timeout) [s]."""


def init_node(ros: RosApi, name: str) -> None:
    """``rospy.init_node`` without taking over the process: our own signal handling, our log handlers kept.

    rospy replaces the root logger's handlers by a file handler in ``$ROS_HOME/log``; the
    handlers in place before (the CLI's stderr) are put back next to it.
    """
    root = logging.getLogger()
    handlers, level = list(root.handlers), root.level
    ros.rospy.init_node(name, anonymous=True, disable_signals=True)
    for handler in handlers:
        if handler not in root.handlers:
            root.addHandler(handler)
    root.setLevel(level)


STAMP_WINDOW_S = (0.5, 0.005)
"""A header stamp this far before / after a message's arrival [s] is taken to be on this machine's
clock (:func:`stamp_on_this_clock`); outside it (clocks out of sync, a replayed recording) the arrival is used."""


def stamp_on_this_clock(msg: Any, arrival: float) -> float | None:
    """Monotonic time of a message's header stamp; None when it is not on this machine's clock.

    A ROS stamp is on the wall clock (``rospy.Time.now()`` of the publisher: a camera stamps its
    exposure, the Kinova driver its joint state when it publishes it); on this machine it is
    ``stamp − (time.time() − time.monotonic())``. It is taken only when it lies within
    :data:`STAMP_WINDOW_S` of the ``arrival`` (monotonic; publisher on this machine, or clocks in
    sync), and never after the arrival.
    """
    stamp = getattr(getattr(msg, "header", None), "stamp", None)
    if stamp is None:
        return None
    t = float(stamp.to_sec())
    if t <= 0.0:
        return None
    on_our_clock = t - (time.time() - time.monotonic())
    before, after = STAMP_WINDOW_S
    if arrival - before <= on_our_clock <= arrival + after:
        return min(on_our_clock, arrival)
    return None


MAX_FRAME_LEAD_S = 0.1
"""Longest extrapolation of the arm past its newest joint state for the self-filter [s]
(:meth:`RosRobotIO.frame_q_ahead`): beyond it the joint state is stale and the watchdog acts."""
PERIOD_SAMPLES = 20
"""Joint states whose median interval is the state period of :meth:`RosRobotIO.frame_q_ahead`."""


class _RateCounter:
    """Arrival times of one topic (bounded), for measured rates, and each message's delivery lag.

    The lag is arrival − header stamp, for the messages whose stamp is on this clock
    (:func:`stamp_on_this_clock`): how late the publisher's messages reached the callback.
    """

    def __init__(self, maxlen: int = 200_000) -> None:
        self.times: deque[float] = deque(maxlen=maxlen)
        self.lags: deque[tuple[float, float]] = deque(maxlen=maxlen)

    def add(self, t: float, stamp: float | None = None) -> None:
        self.times.append(t)
        if stamp is not None:
            self.lags.append((t, t - stamp))

    def stats(self, since: float = -math.inf) -> dict[str, float | int | None]:
        t = np.array([x for x in self.times if x >= since])
        lag = np.array([x for a, x in self.lags if a >= since])
        out: dict[str, float | int | None] = {"count": int(t.size), "rate_hz": None}
        out["interval_p99_ms"] = out["interval_max_ms"] = None
        if t.size >= 2:
            dt = np.diff(t)
            out["rate_hz"] = float((t.size - 1) / (t[-1] - t[0])) if t[-1] > t[0] else None
            out["interval_p99_ms"] = float(np.percentile(dt, 99) * 1e3)
            out["interval_max_ms"] = float(dt.max() * 1e3)
        out["delivery_lag_p99_ms"] = float(np.percentile(lag, 99) * 1e3) if lag.size else None
        out["delivery_lag_max_ms"] = float(lag.max() * 1e3) if lag.size else None
        return out


class RosRobotIO(RobotIO):
    """The real arm (kinova-ros driver) and depth camera, as the control loop sees them.

    Args:
        hw: Topics, rates, limits and camera pose (``[hardware]`` of the config).
        v_max: Model joint velocity limits [rad/s]; scaled by ``hw.max_velocity_scale``. Shape (n,).
        dt: Control period [s] (0.01: the driver needs 100 Hz).
        use_depth: Subscribe to the depth camera and watch its age.
        dry_run: Run everything but never advertise or publish the velocity topic (nor call the
            driver's services).
        ros: Loaded ROS API (default: :func:`~compare.hardware.ros_env.load_ros`).
        replay: Play this recording into the callbacks instead of subscribing (no ROS master;
            implies ``dry_run``; :mod:`compare.hardware.replay`).
        watch_command_topic: Halt on any other publisher of ``hw.velocity_topic`` and on any
            publisher of ``hw.other_command_topics`` (:mod:`compare.hardware.publisher_watch`);
            the read topics are always watched.

    Every message read is checked (:mod:`compare.hardware.validation`): a malformed one is
    dropped with its cause, a second publisher on a read topic halts the arm.

    Raises:
        StartRefused: ``use_depth`` without a calibrated camera transform.
    """

    def __init__(
        self,
        hw: HardwareConfig,
        v_max: np.ndarray,
        dt: float,
        use_depth: bool = True,
        dry_run: bool = False,
        ros: RosApi | None = None,
        replay: Recording | None = None,
        watch_command_topic: bool = True,
    ) -> None:
        self.hw = hw
        self.watch_command_topic = watch_command_topic
        self.nq = len(hw.joint_names)
        self.dt = float(dt)
        self.use_depth = use_depth
        self.replay = replay
        self._feeder: ReplayFeeder | None = None
        dry_run = dry_run or replay is not None
        self.dry_run = dry_run
        if use_depth and not hw.has_camera_transform:
            raise StartRefused(
                "camera transform missing: set hardware.camera_translation_m and hardware.camera_quaternion_xyzw "
                "(the calibrated pose of the depth optical frame in the arm base frame, docs/hardware.md)"
            )
        self._camera_T = (
            transform_from_translation_quaternion(hw.camera_translation_m, hw.camera_quaternion_xyzw)  # type: ignore[arg-type]
            if hw.has_camera_transform
            else None
        )
        self._ros = ros
        v_limit = np.asarray(v_max, dtype=float) * hw.max_velocity_scale
        self._limiter = CommandLimiter(v_limit, hw.max_acceleration_rad_s2, self.dt)
        self.watchdog = Watchdog(
            hw.state_timeout_s, hw.depth_timeout_s if use_depth else None, max(3.0 * self.dt, hw.loop_timeout_s)
        )
        self.watchdog.quiet = True  # until start_clock: zero is expected before the loop runs
        self._lock = threading.RLock()
        self._epoch = time.monotonic()
        self._joint_check = JointStateCheck(hw.joint_names)
        self._info_check = CameraInfoCheck(self._camera_model)
        self._depth_check = DepthCheck()
        self._senders = {t: SenderCheck(t) for t in (hw.joint_state_topic, hw.camera_info_topic, hw.depth_topic)}
        self._check_locks = {name: threading.Lock() for name in ("joint_state", "camera_info", "depth")}
        self._joint: tuple[np.ndarray, np.ndarray, float] | None = None
        self._history: deque[tuple[float, np.ndarray]] = deque(maxlen=300)  # (header stamp, else arrival; q)
        self._camera: CameraModel | None = None
        self._frame: tuple[np.ndarray, float, CameraModel] | None = None
        self._capture_of: dict[float, float] = {}  # arrival → capture time of the last frames (monotonic)
        self._command = np.zeros(self.nq)
        self._command_t: float | None = None
        self._sent = np.zeros(self.nq)
        self._last_publish_t = -math.inf
        self._halt_reason: str | None = None
        self._halt: tuple[str, float] | None = None  # (cause, monotonic time) of a halt before the end of the run
        self._closed = False
        self._pump: threading.Thread | None = None
        self._pump_stop = threading.Event()
        self._tick = threading.Condition()
        self._tick_count = 0
        self.pump_overruns = 0
        self._subs: list[Any] = []
        self._pub: Any = None
        self._nodelay_done: set[int] = set()
        self.rates = {name: _RateCounter() for name in ("joint_state", "depth", "camera_info", "command")}
        self.clamp_count = 0
        self.zero_commands = 0
        self.overruns = 0
        self.bad_messages: dict[str, int] = {}
        self.bad_causes: dict[str, dict[str, int]] = {}
        self.network: ExposureReport | None = None
        self.watch: PublisherWatch | None = None
        self.publishers_at_start: dict[str, list[str]] = {}
        self._clock_start = 0.0
        self.startup_events: list[WatchdogEvent] = []
        self._events_given_next = 0  # watchdog events before this index know their next joint state
        self.start_check: dict[str, Any] = {}
        self._services: dict[str, Any] = {}
        self._master_uri = ""
        self.driver = DriverControl(self._call_service, self.now, enabled=not dry_run)

    # -- lifecycle ---------------------------------------------------------------------------

    def _camera_model(self, width: int, height: int, K: Any) -> CameraModel:
        if self._camera_T is None:
            raise HardwareError("no camera transform")
        hw = self.hw
        return camera_model_from_info(width, height, K, self._camera_T, hw.depth_min_range_m, hw.depth_max_range_m)

    def check_network(self) -> ExposureReport | None:
        """Refuse a master or node reachable beyond loopback, before any connection (nothing is sent).

        Decided from ``ROS_MASTER_URI``, ``ROS_IP``/``ROS_HOSTNAME`` and this machine's listening
        sockets (:func:`~compare.hardware.exposure.check_exposure`); with
        ``hardware.allow_network_master`` the findings are logged and kept in the report instead.
        None when replaying (no ROS graph).

        Raises:
            NetworkExposed: something listens beyond loopback and the user did not opt in.
        """
        if self.replay is not None:
            return None
        if self.network is None:
            self.network = check_exposure(os.environ, sys.argv, self.hw.allow_network_master)
            for problem in self.network.problems:
                log.warning("network exposure allowed (hardware.allow_network_master): %s", problem)
        return self.network

    def _check_own_sockets(self) -> None:
        """After the node started: the sockets this process really listens on (rospy's servers)."""
        report = self.check_network()
        if report is None:
            return
        exposed = exposed_own_sockets()
        report.node_sockets = [s.describe() for s in exposed]
        if exposed and not self.hw.allow_network_master:
            where = ", ".join(s.describe() for s in exposed)
            raise NetworkExposed(f"this node listens on {where}: set ROS_IP=127.0.0.1 (or pass --allow-network-master)")

    def connect(self, master_uri: str | None = None) -> None:
        """Check the network exposure and the master, start the node, subscribe, advertise (unless dry run).

        Raises:
            NetworkExposed: the master or this node would be reachable beyond loopback (checked
                before anything is sent; :meth:`check_network`).
            MasterUnreachable: no master at ``ROS_MASTER_URI``.
            ReplayError: (replay) a topic is not in the recording.
        """
        if self.replay is not None:
            self._connect_replay(self.replay)
            return
        self.check_network()
        ros = self._ros = self._ros or load_ros()
        uri = master_uri or ros.rosgraph.get_master_uri()
        if not master_online(uri, timeout_s=2.0):
            raise MasterUnreachable(f"no ROS master answers at {uri} (start roscore/the driver, or set ROS_MASTER_URI)")
        self._master_uri = uri
        rospy = ros.rospy
        if not rospy.core.is_initialized():
            init_node(ros, self.hw.node_name)
        self._subs.append(
            rospy.Subscriber(
                self.hw.joint_state_topic, ros.JointState, self._on_joint_state, queue_size=1, tcp_nodelay=True
            )
        )
        if self.use_depth:
            self._subs.append(
                rospy.Subscriber(
                    self.hw.camera_info_topic, ros.CameraInfo, self._on_camera_info, queue_size=1, tcp_nodelay=True
                )
            )
            self._subs.append(
                rospy.Subscriber(
                    self.hw.depth_topic, ros.Image, self._on_depth, queue_size=1, buff_size=2**24, tcp_nodelay=True
                )
            )
        if not self.dry_run:
            self._pub = rospy.Publisher(self.hw.velocity_topic, ros.JointVelocity, queue_size=1, tcp_nodelay=True)
            self._services = {
                "stop": (self.hw.stop_service, ros.Stop),
                "start": (self.hw.start_service, ros.Start),
            }
        self._check_own_sockets()
        self._pump = threading.Thread(target=self._pump_loop, name="tpik-hw-pump", daemon=True)
        self._pump.start()

    def _start_watch(self) -> None:
        """Check who publishes on the driver's topics now, then keep watching (:mod:`.publisher_watch`).

        Raises:
            StartRefused: a foreign command publisher, several publishers on a read topic, a
                message from another publisher than the master knows, or no answer from the master.
        """
        if self.replay is not None or self._ros is None or self.watch is not None:
            return
        hw = self.hw
        uri = self._master_uri
        own = str(self._ros.rospy.get_name())
        period = 0.5 * hw.state_timeout_s
        read = [hw.joint_state_topic] + ([hw.camera_info_topic, hw.depth_topic] if self.use_depth else [])
        self.watch = PublisherWatch(
            lambda: topic_publishers(uri, own, timeout_s=period),
            own,
            [hw.velocity_topic, *hw.other_command_topics] if self.watch_command_topic else [],
            read,
            period_s=period,
            silence_s=max(MASTER_SILENCE_MIN_S, hw.state_timeout_s),
            on_halt=self.halt,
            self_check=self._node_alive,
        )
        self.publishers_at_start = self.watch.snapshot()
        for topic in read:
            sender = self._senders[topic].caller_id
            if sender is not None and sender not in self.watch.allowed[topic]:
                raise StartRefused(f"messages on {topic} came from {sender}, which the master does not list")
        self.watch.start()

    def _node_alive(self) -> str | None:
        """Why this node cannot command any more (rospy shut it down), or None.

        The master shuts a node down when another registers under its name: the impostor
        would then pass for the bridge on the command topic.
        """
        rospy = self._ros.rospy if self._ros is not None else None
        if rospy is not None and rospy.core.is_shutdown() and not self._closed:
            return f"this node ({rospy.get_name()}) was shut down (another node took its name?)"
        return None

    def _connect_replay(self, recording: Recording) -> None:
        hw = self.hw
        callbacks: dict[str, Any] = {hw.joint_state_topic: self._on_joint_state}
        if self.use_depth:
            callbacks[hw.camera_info_topic] = self._on_camera_info
            callbacks[hw.depth_topic] = self._on_depth
        recording.require(*callbacks)
        self._feeder = ReplayFeeder(recording, callbacks)
        self._feeder.start()
        self._pump = threading.Thread(target=self._pump_loop, name="tpik-hw-pump", daemon=True)
        self._pump.start()

    def replay_remaining_s(self) -> float | None:
        """Recorded time still to play [s] (None when not replaying)."""
        return None if self._feeder is None else self._feeder.remaining_s()

    def wait_ready(self, timeout_s: float | None = None) -> None:
        """Wait for joint states (and camera info + depth), check the joint state rate, start the publisher watch.

        Raises:
            StartRefused: nothing within ``timeout_s`` (default ``hardware.startup_timeout_s``), the
                driver publishes joint states much slower than ``hardware.state_rate_hz``, or
                someone else publishes on the driver's topics.
        """
        timeout_s = self.hw.startup_timeout_s if timeout_s is None else timeout_s
        deadline = time.monotonic() + timeout_s
        needs = [("joint state", lambda: self._joint is not None, self.hw.joint_state_topic)]
        if self.use_depth:
            needs.append(("camera info", lambda: self._camera is not None, self.hw.camera_info_topic))
            needs.append(("depth frame", lambda: self._frame is not None, self.hw.depth_topic))
        for what, ready, topic in needs:
            while not ready():
                if self._closed:
                    raise StartRefused("stopped while waiting for data")
                if time.monotonic() > deadline:
                    bad = f" ({self.bad_messages})" if self.bad_messages else ""
                    raise StartRefused(f"no {what} on {topic} within {timeout_s:.1f} s{bad}: is the publisher running?")
                time.sleep(0.005)
        self._check_state_stream()
        if self.use_depth:
            age = time.monotonic() - self._frame[1]  # type: ignore[index]
            if age > self.hw.depth_timeout_s:
                raise StartRefused(f"depth frames are stale ({1e3 * age:.0f} ms old) at start")
        self._start_watch()

    def _check_state_stream(self) -> None:
        """Measure the joint-state stream over ~30 expected periods; refuse a slow or gappy one.

        Two checks (docs/hardware.md, "Joint-state rate"): the median interval must give at least
        ``min_state_rate_fraction`` of the expected rate (a driver launched with the default
        ``feedback_publish_rate`` of 0.1 s leaves the 100 Hz loop on 10 Hz data), and the 95th
        percentile of the intervals must stay below 80 % of the watchdog timeout: a watchdog
        tighter than the driver's own jitter would stop and go all run long (over USB, 3 periods
        of 100 Hz = 30 ms is such a watchdog). A single scheduling hiccup does not count.
        """
        hw = self.hw
        expected = hw.expected_state_rate_hz
        t0 = time.monotonic()
        window = max(0.5, 30.0 / expected)
        while time.monotonic() - t0 < window:
            time.sleep(0.01)
        arrivals = np.array([t for t in self.rates["joint_state"].times if t >= t0])
        intervals = np.diff(arrivals)
        median = float(np.median(intervals)) if intervals.size >= 2 else math.inf
        rate = 1.0 / median if median > 0 else 0.0
        gap = float(intervals.max()) if intervals.size else math.inf
        gap_p95 = float(np.percentile(intervals, 95)) if intervals.size else math.inf
        self.start_check = {
            "connection_type": hw.connection_type,
            "expected_state_rate_hz": expected,
            "state_rate_median_hz": rate,
            "state_gap_p95_ms": 1e3 * gap_p95,
            "state_gap_max_ms": 1e3 * gap,
            "state_timeout_ms": 1e3 * hw.state_timeout_s,
        }
        want = expected * hw.min_state_rate_fraction
        launch = f"connection_type {hw.connection_type}, feedback_publish_rate {hw.feedback_publish_rate_s:g} s"
        if rate < want:
            hint = (
                f"launch the driver with feedback_publish_rate:={hw.feedback_publish_rate_s:g}"
                if rate < 0.9 / hw.feedback_publish_rate_s
                else "set hardware.connection_type / feedback_publish_rate_s to what the driver runs with"
            )
            raise StartRefused(
                f"joint states arrive at {rate:.1f} Hz (median), expected {expected:.0f} Hz ({launch}): {hint}"
            )
        if gap_p95 >= 0.8 * hw.state_timeout_s:
            raise StartRefused(
                f"joint states have gaps of {1e3 * gap_p95:.0f} ms (95th percentile; max {1e3 * gap:.0f} ms), "
                f"too close to the watchdog's {1e3 * hw.state_timeout_s:.0f} ms ({launch}): the run would stop and go; "
                "set hardware.connection_type / state_timeout_periods to match the driver"
            )

    def start_driver(self) -> None:
        """Call the driver's ``in/start`` (a previous run may have left it stopped), then wait for a fresh state.

        ``startAPI`` blocks the driver's only thread ~50 ms after a stop: joint states pause meanwhile.

        Raises:
            StartRefused: the service is missing or fails, or no joint state follows.
        """
        if self.dry_run:
            return
        try:
            self.driver.start_now()
        except DriverServiceError as exc:
            raise StartRefused(f"{exc} (hardware.start_service = {self.hw.start_service})") from None
        after = time.monotonic()
        deadline = after + max(1.0, 3.0 * self.hw.state_timeout_s)
        while True:
            with self._lock:
                fresh = self._joint is not None and self._joint[2] > after
            if fresh:
                return
            if time.monotonic() > deadline:
                raise StartRefused("no joint state after in/start: is the driver alive?")
            time.sleep(0.002)

    def _call_service(self, name: str) -> None:
        """Call ``in/stop`` or ``in/start`` (on the driver-control worker thread) and check its answer.

        Raises:
            DriverServiceError: the service is missing, the call fails or the answer is malformed.
        """
        ros = self._ros
        if ros is None or name not in self._services:
            raise DriverServiceError(f"no {name} service (not connected)")
        service, cls = self._services[name]
        rospy = ros.rospy
        from genpy import MessageException  # Deferred: ROS 1 is optional, importable after load_ros()

        # What a failed call raises: a timeout waiting for the service (ROSException), the
        # driver's error (ServiceException), a broken connection (transport errors, socket
        # errors), an answer that does not (de)serialize (genpy).
        failures = (
            rospy.ROSException,
            rospy.ServiceException,
            rospy.exceptions.ROSInternalException,
            MessageException,
            OSError,
        )
        try:
            rospy.wait_for_service(service, timeout=self.hw.service_timeout_s)
            answer = rospy.ServiceProxy(service, cls)()
            check_service_answer(service, answer, cls._response_class, f"{name}_result")
        except failures as exc:
            raise DriverServiceError(f"{service}: {type(exc).__name__}: {exc}") from None
        except HardwareError as exc:
            raise DriverServiceError(str(exc)) from None

    def start_clock(self) -> None:
        """Make :meth:`now` read 0 here (call right before the control loop)."""
        with self._lock:
            shift = time.monotonic() - self._epoch
            self._epoch += shift
            self._clock_start = self._epoch
            self.startup_events.extend(self.watchdog.events)
            self.watchdog.events.clear()
            self._events_given_next = 0
            self.watchdog.quiet = False
            self.zero_commands = self.clamp_count = self.overruns = self.pump_overruns = 0

    def halt(self, reason: str, level: int = logging.WARNING) -> None:
        """Latch zero velocity from now on (Ctrl-C, errors, a foreign publisher) and call ``in/stop``.

        Safe in a signal handler and from any thread. Zero is published at once; ``in/stop`` runs
        on the driver-control thread meanwhile. The first cause is kept (:attr:`halt_cause`).
        """
        if self._halt_reason is None:
            self._halt_reason = reason
            if not self._closed:
                self._halt = (reason, time.monotonic())
            log.log(level, "halt: %s: zero velocity", reason)
        self._publish(time.monotonic())

    @property
    def halt_cause(self) -> str | None:
        """Why the arm was halted before the end of the run (None: it was not)."""
        return self._halt[0] if self._halt is not None else None

    def close(self) -> None:
        """``in/stop``, stream zero velocity for 0.1 s, stop the pump and shut the node down (idempotent)."""
        if self._closed:
            return
        if self.watch is not None:
            self.watch.stop()
        if self._halt_reason is None:
            self._halt_reason = "end of run"
            log.info("halt: end of run: zero velocity")
        self.halt(self._halt_reason, level=logging.INFO)
        self.driver.finish(self._halt_reason or "end of run", timeout_s=self.hw.service_timeout_s + 0.5)
        end = time.monotonic() + _STOP_REPEAT_S
        pump_alive = self._pump is not None and self._pump.is_alive()
        while time.monotonic() < end:  # the stream keeps sending the latched zero
            if not pump_alive:
                self._publish(time.monotonic())
            time.sleep(self.dt)
        self._closed = True
        self.driver.close()
        self._pump_stop.set()
        if self._pump is not None:
            self._pump.join(timeout=1.0)
        if self._feeder is not None:
            self._feeder.stop()
        for sub in self._subs:
            sub.unregister()
        self._subs.clear()
        if self._pub is not None:
            time.sleep(0.02)  # let the queued zero leave the socket
            self._pub.unregister()
            self._pub = None

    # -- RobotIO -----------------------------------------------------------------------------

    def now(self) -> float:
        """Seconds since :meth:`start_clock` (monotonic)."""
        return time.monotonic() - self._epoch

    def read_joints(self) -> JointReading | None:
        """Latest arm joint state, or None when none arrived within the watchdog timeout."""
        with self._lock:
            joint = self._joint
        if joint is None:
            return None
        q, qdot, stamp = joint
        if time.monotonic() - stamp > self.hw.state_timeout_s:
            return None
        return JointReading(q.copy(), qdot.copy(), stamp - self._epoch)

    def q_at(self, stamp_s: float) -> np.ndarray | None:
        """Measured joint positions [rad] at time ``stamp_s`` (this clock): the last state stamped by then.

        A state's time is its header stamp when that lies on this clock, else its arrival
        (:func:`stamp_on_this_clock`): a state delivered late does not count as the arm's pose at its
        arrival. Used to self-filter a depth frame with the arm where it was when the frame was
        taken. None when no state that old is kept (the last 3 s are).
        """
        t = stamp_s + self._epoch
        with self._lock:
            history = list(self._history)
        best = None
        for arrival, q in history:
            if arrival <= t + 1e-4:
                best = q
            else:
                break
        return None if best is None else best.copy()

    def frame_q(self, stamp_s: float) -> np.ndarray | None:
        """Joint positions [rad] when the depth frame that *arrived* at ``stamp_s`` was *taken*.

        The capture time is the image's header stamp when it lies on this machine's clock
        (:func:`stamp_on_this_clock`: camera driver on the same machine, or clocks in sync), else the
        arrival time; the self-filter then places the arm where it was in the image.
        """
        return self.q_at(self._capture_time(stamp_s) - self._epoch)

    def _capture_time(self, stamp_s: float) -> float:
        """Monotonic capture time of the frame that arrived at ``stamp_s`` (this clock); its arrival if unknown."""
        arrival = stamp_s + self._epoch
        with self._lock:
            return self._capture_of.get(round(arrival, 6), arrival)

    def frame_q_ahead(self, stamp_s: float) -> np.ndarray | None:
        """Where the arm may already have been, beyond the newest joint state, when a frame was taken.

        The newest joint state, stamped t_s (its header stamp on this clock, else its arrival:
        :func:`stamp_on_this_clock`; a state that rospy delivers late in a burst keeps its own time), was
        measured up to one state period T before that (the driver samples, then publishes and
        stamps; over USB T ≈ 22 ms, kinova-ros #281; T is the median interval of the stamps), so when
        the frame that arrived at ``stamp_s`` was captured at t_c, the arm was up to
        lead = t_c − (t_s − T) past that state, moving at the velocity last sent q̇_s (the driver
        follows it; its reported velocity lags). The pose returned is q_s + q̇_s · lead, with lead
        clipped to [0, :data:`MAX_FRAME_LEAD_S`]; the self-filter sweeps to it, so a joint state
        lagging the frame leaves no piece of the moving arm in the image (a phantom obstacle).

        Returns:
            The extrapolated joint positions [rad], or None before the first two joint states.
        """
        capture = self._capture_time(stamp_s)
        with self._lock:
            history = list(self._history)[-PERIOD_SAMPLES:]
            sent = self._sent.copy()
        if len(history) < 2:
            return None
        stamps = np.array([t for t, _ in history])
        period = float(np.median(np.diff(stamps)))
        newest_t, newest_q = history[-1]
        lead = min(max(capture - (newest_t - period), 0.0), MAX_FRAME_LEAD_S)
        return newest_q + sent * lead

    def read_depth(self) -> DepthFrame | None:
        """Latest depth frame with the calibrated camera (its age is the caller's to check)."""
        with self._lock:
            frame = self._frame
        if frame is None:
            return None
        depth, stamp, camera = frame
        return DepthFrame(depth, stamp - self._epoch, camera)

    def send_velocity(self, qdot: np.ndarray) -> None:
        """Hold ``qdot`` [rad/s] for the next tick of the command stream (clamped and watched there).

        An all-zero command is also published at once: stopping never waits for a tick.
        """
        now = time.monotonic()
        with self._lock:
            self._command = np.array(qdot, dtype=float, copy=True)
            self._command_t = now
            if not np.any(self._command) and np.any(self._sent):
                self._publish(now)

    def wait(self) -> None:
        """Block until the next tick of the 100 Hz command stream (the loop's clock).

        The loop then reads the latest joint state, solves, and its command goes out at the
        following tick: one period of latency, exactly one message per period.
        """
        with self._tick:
            seen = self._tick_count
            if self._pump is None or not self._pump.is_alive():
                self._tick.wait(self.dt)
                return
            if not self._tick.wait_for(lambda: self._tick_count > seen, timeout=5.0 * self.dt):
                self.overruns += 1
            elif self._tick_count > seen + 1:
                self.overruns += self._tick_count - seen - 1  # the loop missed ticks (the held command was re-sent)

    def stop(self) -> None:
        """Command zero velocity (published at once)."""
        self.send_velocity(np.zeros(self.nq))

    # -- publishing ----------------------------------------------------------------------------

    def _times(self, now: float) -> tuple[float, float | None, float | None, float | None]:
        """(now, state, depth, command) times on this clock, for the watchdog (under the lock)."""
        e = self._epoch
        return (
            now - e,
            self._joint[2] - e if self._joint else None,
            self._frame[1] - e if self._frame else None,
            self._command_t - e if self._command_t is not None else None,
        )

    def _publish(self, now: float) -> None:
        with self._lock:
            if self._halt_reason is not None:
                reason: str | None = self._halt_reason
            else:
                reason = self.watchdog.check(*self._times(now))
            if not self.watchdog.quiet:  # in/stop on a halt or a trip, in/start when fresh again
                trip = None if reason is None or reason == NO_COMMAND_YET else reason
                driver_reason = self.driver.update(trip, self._halt_reason is not None)
                reason = reason or driver_reason
            if reason is not None:
                out = np.zeros(self.nq)
            else:
                out, why = self._limiter.apply(self._command, self._sent)
                if why is not None:
                    self.clamp_count += 1
                    level = logging.INFO if self.clamp_count == 1 else logging.DEBUG
                    log.log(level, "command %s (%d so far; counted in the summary)", why, self.clamp_count)
            self._sent = out
            if not np.any(out):
                self.zero_commands += 1
            self._last_publish_t = now
            self.rates["command"].add(now)
            pub = self._pub
        if pub is not None:
            deg_s = rad_s_to_deg_s(out)
            msg = self._ros.JointVelocity(*(float(v) for v in deg_s))  # type: ignore[union-attr]
            try:
                pub.publish(msg)
            except Exception as exc:  # rospy raises on shutdown; never let a publish kill the stop path
                log.error("publishing the velocity command failed: %s", exc)

    def _pump_loop(self) -> None:
        """The command stream: one message per period on a fixed schedule, plus immediate zeros.

        At each tick the held command goes out (through clamps and watchdog) and the control
        loop is woken. Between ticks the data ages are checked every millisecond: zero is sent at
        once when the arm is commanded to move and the watchdog trips.
        """
        next_tick = time.monotonic()
        while not self._pump_stop.is_set():
            now = time.monotonic()
            if now >= next_tick:
                self._publish(now)
                with self._tick:
                    self._tick_count += 1
                    self._tick.notify_all()
                next_tick += self.dt
                if now - next_tick > self.dt:  # this thread was starved: restart the schedule
                    self.pump_overruns += 1
                    next_tick = now + self.dt
                self._set_nodelay()
                continue
            with self._lock:
                stale = bool(np.any(self._sent)) and self.watchdog.reason_at(*self._times(now)) is not None
            if stale:
                self._publish(now)
            self._pump_stop.wait(min(0.001, max(0.0, next_tick - time.monotonic())))

    def _set_nodelay(self) -> None:
        """Set TCP_NODELAY on our command sockets.

        roscpp subscribers (the driver) don't ask for it by default, and Nagle's algorithm with
        delayed ACKs would deliver 100 Hz commands in bursts.
        """
        pub = self._pub
        if pub is None:
            return
        for conn in list(getattr(pub.impl, "connections", [])):
            sock = getattr(conn, "socket", None)
            if sock is None or id(sock) in self._nodelay_done:
                continue
            try:
                sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                self._nodelay_done.add(id(sock))
            except OSError:
                pass

    # -- callbacks (rospy threads) -------------------------------------------------------------

    def _bad(self, what: str, exc: MalformedMessage) -> None:
        """Count a dropped message by topic and cause; log the first of each cause, then every 100th / 10000th."""
        with self._lock:
            self.bad_messages[what] = self.bad_messages.get(what, 0) + 1
            causes = self.bad_causes.setdefault(what, {})
            causes[exc.kind] = causes.get(exc.kind, 0) + 1
            first_of_kind = causes[exc.kind] == 1
            count = self.bad_messages[what]
        if first_of_kind or count in (100, 10_000):
            log.warning("dropped %s message (%d so far): %s", what, count, exc)

    def _sender_ok(self, what: str, topic: str, msg: Any) -> bool:
        """False (and a halt) when ``msg`` comes from another publisher than the topic's first."""
        cause = self._senders[topic].cause(msg)
        if cause is None:
            return True
        self._bad(what, MalformedMessage("second publisher", cause))
        self.halt(cause)
        return False

    def _on_joint_state(self, msg: Any) -> None:
        arrival = time.monotonic()
        with self._check_locks["joint_state"]:  # rospy calls back from one thread per publisher
            if not self._sender_ok("joint_state", self.hw.joint_state_topic, msg):
                return
            try:
                q, qdot = self._joint_check.parse(msg.name, msg.position, msg.velocity, header_stamp_s(msg), arrival)
            except MalformedMessage as exc:
                self._bad("joint_state", exc)
                return
        with self._lock:
            # Arrival read under the lock: a watchdog check that held the lock first judged a
            # time before this state's arrival, so a trip never overlooks a state it could see.
            now = time.monotonic()
            self._joint = (q, qdot, now)
            # The self-filter's history is kept on the driver's stamps (when on this clock): a state
            # delivered late, in a burst after a starved spell, is placed when it was published.
            stamp = stamp_on_this_clock(msg, now)
            measured = now if stamp is None else stamp
            if self._history:
                measured = max(measured, self._history[-1][0])  # in order, for q_at's scan
            self._history.append((measured, q))
            # Every verdict since the previous state judged that state (or none): this is the next one.
            events = self.watchdog.events
            for e in events[self._events_given_next :]:
                e.next_state_t_s = now - self._epoch
            self._events_given_next = len(events)
        self.rates["joint_state"].add(now, stamp)

    def _on_camera_info(self, msg: Any) -> None:
        now = time.monotonic()
        with self._check_locks["camera_info"]:
            if not self._sender_ok("camera_info", self.hw.camera_info_topic, msg):
                return
            try:
                stamp_s = header_stamp_s(msg)
                cam = self._info_check.parse(msg.width, msg.height, msg.K, msg.header.frame_id, stamp_s, now)
            except MalformedMessage as exc:
                self._bad("camera_info", exc)
                return
        with self._lock:
            self._camera = cam
        self.rates["camera_info"].add(now)

    def _on_depth(self, msg: Any) -> None:
        now = time.monotonic()
        with self._check_locks["depth"]:
            if not self._sender_ok("depth", self.hw.depth_topic, msg):
                return
            cam = self._camera
            if cam is None:  # normal for the first frames: camera_info comes on its own connection
                return
            try:
                depth = self._depth_check.parse(cam, self._info_check.frame_id, msg, header_stamp_s(msg), now)
            except MalformedMessage as exc:
                self._bad("depth", exc)
                return
        stamp = stamp_on_this_clock(msg, now)
        capture = now if stamp is None else stamp
        with self._lock:
            self._frame = (depth, now, cam)
            self._capture_of[round(now, 6)] = capture
            while len(self._capture_of) > 16:
                self._capture_of.pop(next(iter(self._capture_of)))
        self.rates["depth"].add(now, stamp)

    # -- report --------------------------------------------------------------------------------

    def _event_report(self) -> list[dict[str, Any]]:
        """Watchdog events with the joint-state arrivals around each one (controller clock, s).

        ``state_t_s`` is the arrival of the latest joint state the verdict was judged on and
        ``next_state_t_s`` the first arrival after it (None: none), recorded when it arrived. A
        joint-state trip at ``t_s`` is justified when ``next_state_t_s`` is None or not before
        ``t_s``: the bridge held no fresher state than the one it judged stale.
        """
        with self._lock:
            return [
                {
                    "t_s": e.t_s,
                    "reason": e.reason,
                    "message": e.message,
                    "state_t_s": e.state_t_s,
                    "next_state_t_s": e.next_state_t_s,
                }
                for e in self.watchdog.events
            ]

    def report(self) -> dict[str, Any]:
        """Measured rates, watchdog events and counters since :meth:`start_clock` (for summary.json)."""
        since = self._clock_start
        return {
            "dry_run": self.dry_run,
            "replay": [str(b) for b in self.replay.bags] if self.replay is not None else None,
            "connection_type": self.hw.connection_type,
            "clock_start_monotonic_s": self._clock_start,
            "rates": {name: counter.stats(since) for name, counter in self.rates.items()},
            "watchdog_events": self._event_report(),
            "startup_watchdog_events": [e.message for e in self.startup_events],
            "clamped_commands": self.clamp_count,
            "zero_commands": self.zero_commands,
            "loop_overruns": self.overruns,
            "stream_overruns": self.pump_overruns,
            "command_sockets_nodelay": len(self._nodelay_done),
            "ignored_messages": dict(self.bad_messages),
            "ignored_message_causes": {topic: dict(c) for topic, c in self.bad_causes.items()},
            "halt_cause": self.halt_cause,
            "halt_t_s": self._halt[1] - since if self._halt is not None else None,
            "network": self.network.as_dict() if self.network is not None else None,
            "publishers_at_start": dict(self.publishers_at_start),
            "publisher_watch": self.watch.report(since) if self.watch is not None else None,
            "state_timeout_s": self.hw.state_timeout_s,
            "start_check": dict(self.start_check),
            "driver_services": [
                {
                    "service": c.service,
                    "cause": c.cause,
                    "t_s": c.t_s,
                    "duration_ms": c.duration_ms,
                    "ok": c.ok,
                    "error": c.error,
                }
                for c in self.driver.calls
            ],  # fmt: skip
            "depth_timeout_s": self.hw.depth_timeout_s if self.use_depth else None,
        }

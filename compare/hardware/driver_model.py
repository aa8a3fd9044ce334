"""Timing model of the kinova-ros driver and the Jaco²'s controller (no ROS, no threads).

What it reproduces (docs/hardware.md, "The driver model"; upstream files cited there):

* **One spin thread** (``kinova_arm_driver.cpp``: ``ros::spin()`` after constructing the arm,
  the action servers and the trajectory controller). Every callback of the node runs on it,
  one after the other, in the order it was queued (roscpp's callback queue is FIFO).
* **The status timer** (``kinova_arm.cpp``: ``createTimer(status_interval_seconds)`` →
  ``statusTimer`` → ``publishJointAngles``, ``publishToolPosition``, ``publishToolWrench``,
  ``publishFingerPosition``): nine blocking API calls (:data:`STATUS_CALLS`), each taking
  :meth:`DriverTiming.call_s`; the joint angles are read by the second call and
  ``out/joint_state`` is published after the fifth. roscpp re-arms a timer only after its
  callback has run (``TimerManager::schedule``/``updateNext``): a callback longer than the
  period makes the next one due at once, so on USB the timer runs back to back.
* **The velocity subscriber** (``subscribe("in/joint_velocity", 1, ...)``): a subscription
  queue of one message. A message arriving while one is waiting replaces it (the older one
  is dropped) without queueing a second callback; the callback takes the newest message when
  it finally runs. It calls ``sendAdvanceTrajectory`` (one API call) unless the arm is
  stopped (``kinova_comm.cpp``: ``setJointVelocities``, ``isStopped``).
* **The arm's controller**: a 10 ms cycle (kinova-ros README, "Note on publish frequency")
  taking one point per cycle from a bounded trajectory FIFO (2000 points); an empty FIFO
  means no motion in that cycle.
* **``in/stop`` and ``in/start``** (``kinova_arm.cpp`` service callbacks → ``kinova_comm.cpp``
  ``stopAPI``: software stop, ``stopControlAPI``, ``eraseAllTrajectories``; ``startAPI``:
  if stopped ``stopControlAPI``, 50 ms sleep, then ``startControlAPI``). Services are
  callbacks of the same spin thread.

USB and Ethernet differ only by the duration of one API call (:meth:`DriverTiming.for_connection`):
on USB ~2 ms (nine calls ≈ 19 ms, states at ~45 Hz as users report 40–60 Hz in kinova-ros
issues #281, #372, and Kinova support's "each API call takes several ms" in #233), on
Ethernet ~0.3 ms (100 Hz states).

The model is a discrete-event simulation driven by :meth:`KinovaDriverModel.advance`: the
stand-in calls it in real time with the wall clock, the tests in virtual time. The plant is
reached through two callbacks: ``apply(t, velocity_deg_s | None)`` once per controller cycle
and ``read_q()`` when the joint angles are read.
"""

from __future__ import annotations

import math
import threading
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from compare.arguments import ArgumentParser, positive_float

CONNECTIONS = ("usb", "ethernet")

STATUS_CALLS = (
    "getFingerPositions",
    "getJointAngles",
    "getAngularCommand",
    "getJointVelocities",
    "getJointTorques",
    "getCartesianPosition",
    "getCartesianCommand",
    "getCartesianForce",
    "getFingerPositions",
)
"""Blocking API calls of one ``statusTimer`` callback, in order (``kinova_arm.cpp``)."""
SAMPLE_CALL = 1
"""Index in :data:`STATUS_CALLS` of the call that reads the joint angles."""
PUBLISH_AFTER_CALL = 4
"""``out/joint_state`` is published when this call (the last of ``publishJointAngles``) returns."""


@dataclass(frozen=True)
class DriverTiming:
    """Timing parameters of the driver and the arm.

    One blocking API call lasts ``call_base_s + Exp(call_spread_s)`` (a floor plus an
    exponential tail: USB transfers wait for the arm's 10 ms cycle now and then).

    Attributes:
        connection: ``usb`` or ``ethernet`` (the driver's ``connection_type``).
        call_base_s: Shortest duration of one blocking API call [s].
        call_spread_s: Mean of the exponential part of a call [s].
        status_interval_s: ``status_interval_seconds`` (launch arg ``feedback_publish_rate``) [s].
        control_cycle_s: The arm controller's cycle [s].
        fifo_capacity: Points the trajectory FIFO holds.
        start_sleep_s: Sleep inside ``startAPI`` after a software stop [s].
        stopped_callback_s: Duration of a velocity callback while stopped (no API call) [s].
    """

    connection: str = "usb"
    call_base_s: float = 0.0012
    call_spread_s: float = 0.0009
    status_interval_s: float = 0.01
    control_cycle_s: float = 0.01
    fifo_capacity: int = 2000
    start_sleep_s: float = 0.05
    stopped_callback_s: float = 1e-5

    def __post_init__(self) -> None:
        if self.connection not in CONNECTIONS:
            raise ValueError(f"connection must be one of {CONNECTIONS}, got {self.connection!r}")
        if not (self.call_base_s >= 0.0 and self.call_spread_s >= 0.0):
            raise ValueError("API call durations must be >= 0")
        if not (self.status_interval_s > 0.0 and self.control_cycle_s > 0.0 and self.fifo_capacity > 0):
            raise ValueError("status interval, control cycle and FIFO capacity must be > 0")

    @classmethod
    def for_connection(cls, connection: str, status_interval_s: float = 0.01) -> DriverTiming:
        """Typical timing of a USB or an Ethernet connection (module docstring)."""
        if connection == "usb":
            return cls("usb", 0.0012, 0.0009, status_interval_s)
        if connection == "ethernet":
            return cls("ethernet", 0.0002, 0.0001, status_interval_s)
        raise ValueError(f"connection must be one of {CONNECTIONS}, got {connection!r}")


@dataclass
class ServiceTicket:
    """A pending ``in/stop`` or ``in/start`` call; ``done`` is set when the spin thread has run it."""

    name: str
    requested_t: float
    done_t: float | None = None
    done: threading.Event = field(default_factory=threading.Event)


@dataclass(frozen=True)
class StatePublished:
    """One ``out/joint_state`` message: published at ``t``, angles read at ``sample_t`` [s]."""

    t: float
    sample_t: float
    q: np.ndarray


@dataclass
class CommandFate:
    """What became of one velocity message (``seq`` = arrival order)."""

    arrival_t: float
    deg_s: np.ndarray
    outcome: str = "queued"
    """``queued`` → ``dropped`` (subscription queue), ``ignored`` (arm stopped), ``overflow``
    (FIFO full), ``in_fifo`` → ``executed`` or ``erased`` (by ``in/stop``)."""
    callback_t: float | None = None
    executed_t: float | None = None


@dataclass
class _Callback:
    kind: str
    steps: list[tuple[float, Callable[[float], None] | None]]
    index: int = 0


class KinovaDriverModel:
    """The driver's spin thread, subscription queue, status timer, services and the arm's FIFO.

    Args:
        timing: Durations and sizes.
        apply: Called once per controller cycle with the cycle's start time [s] and the point
            executed (deg/s, shape (7,)), or None when the FIFO was empty or the arm stopped.
        read_q: Current joint positions of the plant [rad] (called when the angles are read).
        t0: Start time [s] (the driver's constructor has run: control API started, FIFO empty).
        seed: Seed of the call-duration generator.
        on_state: Called with every :class:`StatePublished` as it happens.
    """

    def __init__(
        self,
        timing: DriverTiming,
        apply: Callable[[float, np.ndarray | None], None],
        read_q: Callable[[], np.ndarray],
        t0: float = 0.0,
        seed: int = 0,
        on_state: Callable[[StatePublished], None] | None = None,
    ) -> None:
        self.timing = timing
        self._apply = apply
        self._read_q = read_q
        self._on_state = on_state
        self._rng = np.random.default_rng(seed)
        self.time = float(t0)
        self._timer_next = t0 + timing.status_interval_s
        self._timer_queued = False
        rng_phase = float(self._rng.uniform(0.0, timing.control_cycle_s))
        self._cycle_next = t0 + rng_phase
        self._callbacks: deque[_Callback] = deque()
        self._running: _Callback | None = None
        self._step_end = math.inf
        self._sub_queue: deque[int] = deque(maxlen=1)
        self._fifo: deque[int] = deque()
        self._sample: tuple[float, np.ndarray] | None = None
        self.stopped = False
        self.commands: list[CommandFate] = []
        self.states: list[StatePublished] = []
        self.services: list[ServiceTicket] = []
        self.fifo_peak = 0
        self.cycles = 0
        self.cycles_moving = 0

    # -- inputs ----------------------------------------------------------------------------

    def receive_velocity(self, t: float, deg_s: Sequence[float]) -> int:
        """A ``kinova_msgs/JointVelocity`` arrives at ``t`` [s]; returns its sequence number.

        roscpp's subscription queue of size 1: if a message is already waiting, it is dropped
        and replaced; a callback is queued only when none was waiting.
        """
        self.advance(t)
        seq = len(self.commands)
        self.commands.append(CommandFate(max(t, self.time), np.asarray(deg_s, dtype=float).copy()))
        if self._sub_queue:
            self.commands[self._sub_queue[0]].outcome = "dropped"
            self._sub_queue.clear()
            self._sub_queue.append(seq)
        else:
            self._sub_queue.append(seq)
            self._callbacks.append(_Callback("velocity", [(0.0, self._velocity_callback)]))
        return seq

    def request_service(self, t: float, name: str) -> ServiceTicket:
        """Queue an ``in/stop`` (``stop``) or ``in/start`` (``start``) call arriving at ``t`` [s]."""
        if name not in ("stop", "start"):
            raise ValueError(f"unknown service {name!r}")
        self.advance(t)
        ticket = ServiceTicket(name, max(t, self.time))
        self.services.append(ticket)
        steps: list[tuple[float, Callable[[float], None] | None]]
        if name == "stop":
            steps = [
                (0.0, self._software_stop),
                (self._call(), None),  # stopControlAPI
                (self._call(), self._erase_fifo),  # eraseAllTrajectories
            ]
        else:
            steps = [(0.0, self._software_start)]
            if self.stopped:
                steps += [(self._call(), None), (self.timing.start_sleep_s, None)]  # stopControlAPI, sleep
            steps.append((self._call(), None))  # startControlAPI
        steps.append((0.0, lambda now: self._service_done(ticket, now)))
        self._callbacks.append(_Callback(f"service:{name}", steps))
        return ticket

    # -- simulation ------------------------------------------------------------------------

    def next_event_t(self) -> float:
        """Time of the next internal event [s] (call :meth:`advance` by then)."""
        spin = self._step_end if self._running is not None else (self.time if self._callbacks else math.inf)
        timer = math.inf if self._timer_queued else self._timer_next
        return min(spin, timer, self._cycle_next)

    def advance(self, t: float) -> None:
        """Run every event up to time ``t`` [s] (no-op if ``t`` is in the past)."""
        while True:
            if self._running is None and self._callbacks:
                self._start(self._callbacks.popleft(), self.time)
                continue
            timer = math.inf if self._timer_queued else self._timer_next
            spin = self._step_end if self._running is not None else math.inf
            nxt = min(timer, spin, self._cycle_next)
            if nxt > t:
                break
            self.time = max(self.time, nxt)
            if nxt == self._cycle_next:
                self._cycle(nxt)
            elif nxt == timer:
                self._timer_queued = True
                self._callbacks.append(_Callback("status", self._status_steps()))
            else:
                self._finish_step(nxt)
        self.time = max(self.time, t)

    # -- internals -------------------------------------------------------------------------

    def _call(self) -> float:
        tm = self.timing
        return tm.call_base_s + (float(self._rng.exponential(tm.call_spread_s)) if tm.call_spread_s > 0 else 0.0)

    def _status_steps(self) -> list[tuple[float, Callable[[float], None] | None]]:
        steps: list[tuple[float, Callable[[float], None] | None]] = []
        for i in range(len(STATUS_CALLS)):
            action: Callable[[float], None] | None = None
            if i == SAMPLE_CALL:
                action = self._sample_angles
            elif i == PUBLISH_AFTER_CALL:
                action = self._publish_state
            steps.append((self._call(), action))
        steps.append((0.0, self._rearm_timer))
        return steps

    def _start(self, cb: _Callback, now: float) -> None:
        self._running = cb
        cb.index = 0
        self._step_end = now + cb.steps[0][0]

    def _finish_step(self, now: float) -> None:
        cb = self._running
        assert cb is not None
        action = cb.steps[cb.index][1]
        if action is not None:
            action(now)
        cb.index += 1
        if cb.index >= len(cb.steps):
            self._running = None
            self._step_end = math.inf
        else:
            self._step_end = now + cb.steps[cb.index][0]

    def _cycle(self, now: float) -> None:
        self._cycle_next = now + self.timing.control_cycle_s
        self.cycles += 1
        point = None
        if self._fifo:
            seq = self._fifo.popleft()
            fate = self.commands[seq]
            fate.outcome, fate.executed_t = "executed", now
            point = fate.deg_s
            self.cycles_moving += int(bool(np.any(point)))
        self._apply(now, point)

    def _rearm_timer(self, now: float) -> None:
        """Re-arm the status timer as roscpp's ``TimerManager::updateNext`` does after the callback ran."""
        period = self.timing.status_interval_s
        if self._timer_next <= now:
            self._timer_next += period
        if self._timer_next + period < now:
            self._timer_next = now
        self._timer_queued = False

    def _sample_angles(self, now: float) -> None:
        self._sample = (now, np.array(self._read_q(), dtype=float, copy=True))

    def _publish_state(self, now: float) -> None:
        assert self._sample is not None
        state = StatePublished(now, self._sample[0], self._sample[1])
        self.states.append(state)
        if self._on_state is not None:
            self._on_state(state)

    def _velocity_callback(self, now: float) -> None:
        # Runs at the start of the callback: takes the newest waiting message, then (unless
        # stopped) spends one API call in sendAdvanceTrajectory before the point is in the FIFO.
        seq = self._sub_queue.popleft()
        fate = self.commands[seq]
        fate.callback_t = now
        cb = self._running
        assert cb is not None
        if self.stopped:
            fate.outcome = "ignored"
            cb.steps.append((self.timing.stopped_callback_s, None))
            return
        cb.steps.append((self._call(), lambda t: self._enqueue(seq)))

    def _enqueue(self, seq: int) -> None:
        if self.stopped:  # stopped while the call was in flight (cannot happen: one thread)
            self.commands[seq].outcome = "ignored"
        elif len(self._fifo) >= self.timing.fifo_capacity:
            self.commands[seq].outcome = "overflow"
        else:
            self.commands[seq].outcome = "in_fifo"
            self._fifo.append(seq)
            self.fifo_peak = max(self.fifo_peak, len(self._fifo))

    def _software_stop(self, now: float) -> None:
        self.stopped = True

    def _software_start(self, now: float) -> None:
        self.stopped = False

    def _erase_fifo(self, now: float) -> None:
        for seq in self._fifo:
            self.commands[seq].outcome = "erased"
        self._fifo.clear()

    def _service_done(self, ticket: ServiceTicket, now: float) -> None:
        ticket.done_t = now
        ticket.done.set()

    # -- statistics ------------------------------------------------------------------------


@dataclass(frozen=True)
class StreamStats:
    """What reached the arm and what came back, for a command stream (virtual time).

    Attributes:
        state_rate_hz: Joint states per second.
        state_gap_p99_ms: 99th percentile of the intervals between joint states [ms].
        state_gap_max_ms: Longest interval [ms].
        commands_executed_per_s: Velocity points executed by the arm per second.
        commands_dropped_fraction: Messages dropped by the subscription queue.
        latency_median_ms: Arrival at the driver → execution by the arm, median [ms].
        latency_p99_ms: Same, 99th percentile [ms].
        fifo_peak: Most points waiting in the FIFO.
        speed_ratio: Executed motion / commanded motion (1 = the arm moves as commanded).
    """

    state_rate_hz: float
    state_gap_p99_ms: float
    state_gap_max_ms: float
    commands_executed_per_s: float
    commands_dropped_fraction: float
    latency_median_ms: float
    latency_p99_ms: float
    fifo_peak: int
    speed_ratio: float


def stream_stats(model: KinovaDriverModel, t0: float, t1: float) -> StreamStats:
    """Statistics of ``model`` between ``t0`` and ``t1`` [s] (commands arrived in that window)."""
    st = np.array([s.t for s in model.states if t0 <= s.t <= t1])
    gaps = np.diff(st) * 1e3 if st.size > 1 else np.array([math.inf])
    window = [c for c in model.commands if t0 <= c.arrival_t <= t1]
    executed = [c for c in window if c.outcome == "executed"]
    latency = np.array([c.executed_t - c.arrival_t for c in executed]) * 1e3  # type: ignore[operator]
    commanded = sum(float(np.abs(c.deg_s).sum()) for c in window)
    moved = sum(float(np.abs(c.deg_s).sum()) for c in executed)
    return StreamStats(
        state_rate_hz=(st.size - 1) / (st[-1] - st[0]) if st.size > 1 else 0.0,
        state_gap_p99_ms=float(np.percentile(gaps, 99)),
        state_gap_max_ms=float(gaps.max()),
        commands_executed_per_s=len(executed) / (t1 - t0),
        commands_dropped_fraction=sum(c.outcome == "dropped" for c in window) / max(1, len(window)),
        latency_median_ms=float(np.median(latency)) if latency.size else math.nan,
        latency_p99_ms=float(np.percentile(latency, 99)) if latency.size else math.nan,
        fifo_peak=model.fifo_peak,
        speed_ratio=moved / commanded if commanded > 0 else math.nan,
    )


def simulate_stream(
    timing: DriverTiming,
    duration_s: float = 10.0,
    rate_hz: float = 100.0,
    jitter_s: float = 0.0005,
    seed: int = 0,
) -> KinovaDriverModel:
    """The driver model fed a constant 10 deg/s command on every joint at ``rate_hz`` (virtual time).

    Arrival times are ``k / rate_hz`` plus a uniform jitter of ±``jitter_s`` (network and sender
    scheduling), kept in order.
    """
    rng = np.random.default_rng(seed + 1)
    q = np.zeros(7)

    def apply(t: float, deg_s: np.ndarray | None) -> None:
        if deg_s is not None:
            q[:] += np.radians(deg_s) * timing.control_cycle_s

    model = KinovaDriverModel(timing, apply, lambda: q, seed=seed)
    n = int(duration_s * rate_hz)
    arrivals = np.arange(1, n + 1) / rate_hz + rng.uniform(-jitter_s, jitter_s, n)
    command = np.full(7, 10.0)
    for t in np.maximum.accumulate(arrivals):
        model.receive_velocity(float(t), command)
    model.advance(duration_s + 0.5)
    return model


_WARM_UP_S = 1.0
"""Start of the window :func:`tradeoff_table` measures [s] (the stream settles before it)."""


def tradeoff_table(intervals_s: Sequence[float] = (0.01, 0.02, 0.04, 0.1), duration_s: float = 20.0) -> str:
    """Markdown table: per connection and ``feedback_publish_rate``, what the bridge gets (docs/hardware.md)."""
    rows = [
        "| connection | feedback_publish_rate [s] | joint states [Hz] | state gap p99 / max [ms] | "
        "commands executed [1/s] | dropped | latency median / p99 [ms] | speed ratio |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for connection in CONNECTIONS:
        for interval in intervals_s:
            model = simulate_stream(DriverTiming.for_connection(connection, interval), duration_s)
            s = stream_stats(model, _WARM_UP_S, duration_s)
            rows.append(
                f"| {connection} | {interval:g} | {s.state_rate_hz:.1f} | {s.state_gap_p99_ms:.0f} / "
                f"{s.state_gap_max_ms:.0f} | {s.commands_executed_per_s:.1f} | "
                f"{100 * s.commands_dropped_fraction:.0f} % | "
                f"{s.latency_median_ms:.1f} / {s.latency_p99_ms:.1f} | {s.speed_ratio:.2f} |"
            )
    return "\n".join(rows)


def main(argv: list[str] | None = None) -> int:
    """``python -m compare.hardware.driver_model``: print the trade-off table of docs/hardware.md."""
    parser = ArgumentParser(
        prog="python -m compare.hardware.driver_model",
        description=__doc__.split("\n")[0] + "\n\nPrints, per connection (USB, Ethernet) and "
        "feedback_publish_rate [s], the joint-state\nrate [Hz], state gaps [ms], commands executed and "
        "dropped, command latency [ms] and speed ratio\n(Markdown; virtual time, no ROS).",
    )
    parser.add_argument(
        "--duration",
        type=positive_float,
        default=20.0,
        help=f"virtual time per row [s], more than the {_WARM_UP_S:g} s warm-up",
    )
    args = parser.parse_args(argv)
    if args.duration <= _WARM_UP_S:
        parser.error(f"argument --duration: expected more than the {_WARM_UP_S:g} s warm-up, got {args.duration:g}")
    print(tradeoff_table(duration_s=args.duration))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

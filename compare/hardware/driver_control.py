"""When the bridge calls the driver's ``in/stop`` and ``in/start`` (no ROS import here).

Zero velocity alone does not stop a Jaco² at once: points already in the arm's trajectory FIFO
run first (kinova-ros README, "Note on publish frequency"). ``in/stop`` (``KinovaComm::stopAPI``)
stops the control API, erases the FIFO and makes the driver ignore velocity commands until
``in/start``. The policy:

* every halt path calls ``in/stop`` once: a latched halt (Ctrl-C, SIGTERM, an error), a
  watchdog trip (stale joint state, stale depth, stalled loop) and the end of the run;
* after a watchdog trip, when the data is fresh again, ``in/start`` is called and commands
  stay zero until it has returned and fresh data has come again: ``startAPI`` blocks the
  driver's only thread ~50 ms, so the joint states pause, and that pause is not a new trip
  (unless it lasts :data:`RESTART_GRACE_S`); a latched halt is never followed by a start;
* before the first run ``in/start`` is called synchronously (a previous run left the driver
  stopped): :meth:`DriverControl.start_now`.

Service calls run on a worker thread: the command stream (which calls :meth:`DriverControl.update`
at every tick, under its lock) never blocks on the driver, and keeps streaming zeros meanwhile.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

from compare.hardware.exceptions import HardwareError

log = logging.getLogger(__name__)


RESTART_GRACE_S = 1.0
"""After ``in/start`` returns, data must be fresh again within this time, else it is a new trip [s]."""


class DriverServiceError(HardwareError):
    """An ``in/stop`` or ``in/start`` call failed (service missing, driver error, timeout)."""


@dataclass(frozen=True)
class ServiceCall:
    """One call of a driver service.

    Attributes:
        service: ``stop`` or ``start``.
        cause: Why it was called.
        t_s: Request time on the controller's clock [s].
        duration_ms: Until the driver answered [ms].
        ok: Whether it succeeded.
        error: The failure, if any.
    """

    service: str
    cause: str
    t_s: float
    duration_ms: float
    ok: bool
    error: str | None = None


class DriverControl:
    """The ``in/stop``/``in/start`` policy of the module docstring.

    Args:
        call: Calls the service ``stop`` or ``start`` and returns when the driver answered;
            raises :class:`DriverServiceError` on failure.
        clock: Controller time [s] (for the record).
        enabled: False (dry run, replay): nothing is ever called, nothing is blocked.
    """

    def __init__(self, call: Callable[[str], None], clock: Callable[[], float], enabled: bool = True) -> None:
        self._call = call
        self._clock = clock
        self.enabled = enabled
        self.calls: list[ServiceCall] = []
        self._requests: queue.Queue[tuple[str, str] | None] = queue.Queue()
        self._lock = threading.Lock()
        self._state = "running"  # running | stopped (in/stop requested) | starting (in/start requested)
        # | restarted (in/start returned, waiting for fresh data)
        self._restarted_t = 0.0
        self._halted = False
        self._last_submitted: str | None = None
        self._pending = 0
        self._idle = threading.Event()
        self._idle.set()
        self._worker: threading.Thread | None = None

    @property
    def stopped(self) -> bool:
        """Whether the driver was asked to stop and has not been restarted: commands are ignored by it."""
        return self._state != "running"

    def start_now(self, cause: str = "before the run") -> None:
        """Call ``in/start`` and wait for it (before the first command).

        Raises:
            DriverServiceError: the call failed.
        """
        if not self.enabled:
            return
        self._run("start", cause)
        last = self.calls[-1]
        if not last.ok:
            raise DriverServiceError(f"in/start failed: {last.error}")
        with self._lock:
            self._state, self._last_submitted = "running", "start"

    def update(self, cause: str | None, halted: bool) -> str | None:
        """Called at every command tick with why the command must be zero (None: it need not be).

        Args:
            cause: The halt or watchdog reason, or None when the data is fresh.
            halted: The halt is latched (never restart).

        Returns:
            A reason to keep the command at zero because of the driver's state, or None.
        """
        if not self.enabled:
            return None
        with self._lock:
            self._halted = self._halted or halted
            if self._state == "restarted":
                if cause is None:
                    self._state = "running"
                elif halted or self._clock() - self._restarted_t > RESTART_GRACE_S:
                    self._state = "stopped"
                    self._submit("stop", cause)
            elif cause is not None and self._state in ("running", "starting"):
                self._state = "stopped"
                self._submit("stop", cause)
            elif cause is None and self._state == "stopped" and not self._halted:
                self._state = "starting"
                self._submit("start", "data fresh again after the watchdog")
            state = self._state
        if state == "starting":
            return "driver stopped (in/stop); waiting for in/start"
        if state == "restarted":
            return "driver restarted (in/start); waiting for fresh data"
        return "driver stopped (in/stop)" if state == "stopped" else None

    def finish(self, cause: str, timeout_s: float) -> None:
        """End of the run: make sure the last call is an ``in/stop``, then wait for the worker."""
        if not self.enabled:
            return
        with self._lock:
            self._halted = True
            self._state = "stopped"
            if self._last_submitted != "stop":
                self._submit("stop", cause)
        self.wait_idle(timeout_s)

    def wait_idle(self, timeout_s: float) -> bool:
        """Wait until no call is pending; False on timeout."""
        return self._idle.wait(timeout_s)

    def close(self) -> None:
        """Stop the worker thread (after its pending calls)."""
        if self._worker is not None:
            self._requests.put(None)
            self._worker.join(timeout=5.0)
            self._worker = None

    # -- worker ----------------------------------------------------------------------------

    def _submit(self, service: str, cause: str) -> None:
        """Queue a call (under ``self._lock``)."""
        self._last_submitted = service
        self._pending += 1
        self._idle.clear()
        if self._worker is None:
            self._worker = threading.Thread(target=self._work, name="tpik-hw-driver", daemon=True)
            self._worker.start()
        self._requests.put((service, cause))

    def _work(self) -> None:
        while True:
            item = self._requests.get()
            if item is None:
                return
            service, cause = item
            self._run(service, cause)
            with self._lock:
                if service == "start" and self._state == "starting":
                    if self.calls[-1].ok:
                        self._state, self._restarted_t = "restarted", self._clock()
                    else:  # a failed start leaves the driver stopped for good
                        self._state, self._halted = "stopped", True
                self._pending -= 1
                if self._pending == 0:
                    self._idle.set()

    def _run(self, service: str, cause: str) -> None:
        t = self._clock()
        start = time.monotonic()
        try:
            self._call(service)
            call = ServiceCall(service, cause, t, 1e3 * (time.monotonic() - start), True)
            log.info("in/%s called (%s): answered in %.0f ms", service, cause, call.duration_ms)
        except DriverServiceError as exc:
            call = ServiceCall(service, cause, t, 1e3 * (time.monotonic() - start), False, str(exc))
            log.error("in/%s (%s) failed: %s", service, cause, exc)
        self.calls.append(call)

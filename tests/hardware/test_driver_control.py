"""When ``in/stop`` and ``in/start`` are called: every halt path stops the driver (no ROS needed)."""

from __future__ import annotations

import threading

import pytest

from compare.hardware.driver_control import RESTART_GRACE_S, DriverControl, DriverServiceError


class _Driver:
    """Records the service calls; ``fail`` makes a service raise; ``gate`` holds calls until set."""

    def __init__(self) -> None:
        self.calls: list[str] = []
        self.fail: set[str] = set()
        self.gate = threading.Event()
        self.gate.set()

    def __call__(self, name: str) -> None:
        self.gate.wait(5.0)
        self.calls.append(name)
        if name in self.fail:
            raise DriverServiceError(f"{name} refused")


def _control(enabled: bool = True) -> tuple[DriverControl, _Driver, list[float]]:
    driver, clock = _Driver(), [0.0]
    return DriverControl(driver, lambda: clock[0], enabled=enabled), driver, clock


def test_a_latched_halt_stops_the_driver_once_and_never_restarts_it():
    control, driver, _ = _control()
    control.start_now()
    assert control.update(None, halted=False) is None
    assert "stopped" in control.update("SIGINT received", halted=True)
    control.wait_idle(5.0)
    assert control.update(None, halted=True) is not None  # fresh data does not restart a halt
    control.finish("end of run", timeout_s=5.0)
    assert driver.calls == ["start", "stop"]
    assert [c.cause for c in control.calls] == ["before the run", "SIGINT received"]


@pytest.mark.parametrize(
    "cause",
    [
        "joint state stale: last one 120 ms ago (limit 111 ms)",
        "depth stale: last frame 210 ms ago (limit 200 ms)",
        "control loop stalled: last command 110 ms ago (limit 100 ms)",
    ],
)
def test_a_watchdog_trip_stops_the_driver_and_fresh_data_restarts_it(cause):
    control, driver, clock = _control()
    control.start_now()
    assert control.update(cause, halted=False) == "driver stopped (in/stop)"
    control.wait_idle(5.0)
    assert control.update(cause, halted=False) is not None  # still stale: stays stopped, no second stop
    clock[0] = 1.0
    assert control.update(None, halted=False) is not None  # fresh: in/start requested, still zero
    control.wait_idle(5.0)
    # in/start returned; the pause it caused in the joint states is not a new trip...
    assert "waiting for fresh data" in control.update(cause, halted=False)
    # ...and commands resume with the first fresh data.
    assert control.update(None, halted=False) is None
    control.finish("end of run", timeout_s=5.0)
    assert driver.calls == ["start", "stop", "start", "stop"]
    assert control.calls[1].cause == cause


def test_stale_data_beyond_the_restart_grace_is_a_new_trip():
    control, driver, clock = _control()
    control.start_now()
    control.update("joint state stale", halted=False)
    control.wait_idle(5.0)
    control.update(None, halted=False)
    control.wait_idle(5.0)
    clock[0] = RESTART_GRACE_S + 0.5
    assert control.update("joint state stale", halted=False) == "driver stopped (in/stop)"
    control.wait_idle(5.0)
    assert driver.calls == ["start", "stop", "start", "stop"]


def test_a_trip_while_in_start_is_pending_stops_again_after_it():
    control, driver, _ = _control()
    control.start_now()
    control.update("joint state stale", halted=False)
    control.wait_idle(5.0)
    driver.gate.clear()  # in/start in flight
    control.update(None, halted=False)
    assert control.update("depth stale", halted=False) == "driver stopped (in/stop)"
    driver.gate.set()
    control.wait_idle(5.0)
    assert driver.calls == ["start", "stop", "start", "stop"]
    assert control.stopped


def test_the_end_of_a_run_without_any_trip_stops_the_driver():
    control, driver, _ = _control()
    control.start_now()
    for _ in range(10):
        assert control.update(None, halted=False) is None
    control.finish("end of run", timeout_s=5.0)
    assert driver.calls == ["start", "stop"]


def test_a_failed_start_refuses_the_run_and_a_failed_restart_keeps_the_driver_stopped():
    control, driver, _ = _control()
    driver.fail.add("start")
    with pytest.raises(DriverServiceError, match="in/start failed"):
        control.start_now()
    control, driver, _ = _control()
    control.start_now()
    driver.fail.add("start")
    control.update("joint state stale", halted=False)
    control.wait_idle(5.0)
    control.update(None, halted=False)
    control.wait_idle(5.0)
    for _ in range(5):
        assert control.update(None, halted=False) == "driver stopped (in/stop)"
    control.wait_idle(5.0)
    assert driver.calls == ["start", "stop", "start"]  # no retry loop
    assert not control.calls[-1].ok


def test_dry_run_calls_nothing_and_blocks_nothing():
    control, driver, _ = _control(enabled=False)
    control.start_now()
    assert control.update("joint state stale", halted=True) is None
    control.finish("end of run", timeout_s=1.0)
    assert driver.calls == [] and control.calls == []

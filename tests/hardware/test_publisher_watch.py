"""The publisher watch's rules on hand-made master answers, and the sender check of each message (no ROS)."""

from __future__ import annotations

import threading
from types import SimpleNamespace

import numpy as np
import pytest

from compare.hardware.exceptions import StartRefused
from compare.hardware.master_api import MasterCallFailed
from compare.hardware.publisher_watch import PublisherWatch
from compare.hardware.validation import SenderCheck

CMD = "/j2s7s300_driver/in/joint_velocity"
STATE = "/j2s7s300_driver/out/joint_state"
DEPTH = "/kinect2/sd/image_depth_rect"
ME = "/tpik_compare_1"
DRIVER = "/j2s7s300_driver"
CLEAN = {CMD: [ME], STATE: [DRIVER], DEPTH: ["/kinect2_bridge"], "/rosout": [ME, DRIVER]}


class FakeMaster:
    """Answers of ``getSystemState`` in turn (the last one repeated); an exception is raised."""

    def __init__(self, *answers):
        self.answers = list(answers)
        self.calls = 0

    def __call__(self):
        answer = self.answers[min(self.calls, len(self.answers) - 1)]
        self.calls += 1
        if isinstance(answer, Exception):
            raise answer
        return answer


def _watch(master, halts, clock=None, period_s=0.01, silence_s=0.05):
    kwargs = {"clock": clock} if clock is not None else {}
    return PublisherWatch(master, ME, [CMD], [STATE, DEPTH], period_s, silence_s, halts.append, **kwargs)


def test_only_the_bridge_may_publish_commands_and_only_the_first_publishers_may_feed_it():
    watch = _watch(FakeMaster(CLEAN), [])
    assert watch.snapshot()[STATE] == [DRIVER]
    assert watch.findings(CLEAN) == []
    assert watch.findings({**CLEAN, CMD: [ME, "/teleop"]}) == ["foreign command publisher /teleop"]
    assert watch.findings({**CLEAN, CMD: ["/teleop"]}) == ["foreign command publisher /teleop"]  # even alone
    assert watch.findings({**CLEAN, STATE: [DRIVER, "/spoof"]}) == [f"second publisher /spoof on {STATE}"]
    assert watch.findings({**CLEAN, STATE: ["/spoof"]}) == [f"second publisher /spoof on {STATE}"]  # a replacement
    assert watch.findings({**CLEAN, STATE: []}) == []  # a publisher gone is the watchdog's business


@pytest.mark.parametrize(
    ("answer", "message"),
    [({**CLEAN, CMD: [ME, "/teleop"]}, "foreign command publisher /teleop"),
     ({**CLEAN, STATE: [DRIVER, "/spoof"]}, f"2 publishers on {STATE} (/j2s7s300_driver, /spoof)"),
     (MasterCallFailed("getSystemState: timed out"), "cannot tell who publishes on the driver's topics")],
)  # fmt: skip
def test_the_start_is_refused_on_a_finding_or_a_silent_master(answer, message):
    with pytest.raises(StartRefused, match=message.replace("(", r"\(").replace(")", r"\)")):
        _watch(FakeMaster(answer), []).snapshot()


def test_a_foreign_publisher_halts_once_at_the_first_poll_that_sees_it_and_the_polls_end():
    master = FakeMaster(CLEAN, CLEAN, CLEAN, {**CLEAN, CMD: [ME, "/teleop"]})
    halts: list[str] = []
    done = threading.Event()
    watch = _watch(master, halts)
    watch._on_halt = lambda cause: (halts.append(cause), done.set())
    watch.snapshot()
    watch.start()
    assert done.wait(10.0)
    watch.stop()
    assert halts == ["foreign command publisher /teleop"] and master.calls == 4  # snapshot + 3 polls, no more
    report = watch.report(origin=0.0)
    assert report["cause"] == halts[0] and report["polls"] == 4 and report["failed_polls"] == 0


def test_a_master_silent_longer_than_the_silence_limit_halts_and_a_short_silence_does_not():
    t = [0.0]
    failure = MasterCallFailed("getSystemState: connection refused")
    master = FakeMaster(CLEAN, failure)
    halts: list[str] = []
    watch = _watch(master, halts, clock=lambda: t[0], period_s=0.1, silence_s=1.0)
    watch.snapshot()
    for k in range(1, 10):  # 0.1 … 0.9 s without an answer
        t[0] = 0.1 * k
        assert watch.poll_once() is None
    t[0] = 1.05
    cause = watch.poll_once()
    assert cause is not None and cause.startswith("no answer from the ROS master for 1050 ms") and halts == [cause]
    assert watch.failed_polls == 10


def test_the_period_and_silence_are_checked():
    with pytest.raises(ValueError):
        _watch(FakeMaster(CLEAN), [], period_s=0.2, silence_s=0.1)


def _msg(caller=None):
    msg = SimpleNamespace()
    if caller is not None:
        msg._connection_header = {"callerid": caller, "topic": STATE}
    return msg


def test_each_message_must_come_from_the_topics_first_sender():
    check = SenderCheck(STATE)
    assert check.cause(_msg()) is None  # no connection header (replay): not judged
    assert check.cause(_msg(DRIVER)) is None and check.caller_id == DRIVER
    assert check.cause(_msg(DRIVER)) is None
    assert check.cause(_msg("/spoof")) == f"second publisher /spoof on {STATE}"
    assert check.caller_id == DRIVER


def test_a_joint_state_from_a_second_sender_is_dropped_and_halts_the_bridge():
    from compare.config import HardwareConfig
    from compare.hardware.ros_io import RosRobotIO

    names = tuple(f"joint_{i}" for i in range(1, 8))
    io = RosRobotIO(HardwareConfig(joint_names=names), np.full(7, 0.6), 0.01, use_depth=False, dry_run=True)
    io.start_clock()

    def state(caller, stamp, q):
        msg = SimpleNamespace(name=list(names), position=[q] * 7, velocity=[], header=SimpleNamespace(
            stamp=SimpleNamespace(to_sec=lambda: stamp)), _connection_header={"callerid": caller})  # fmt: skip
        io._on_joint_state(msg)

    state(DRIVER, 10.00, 0.1)
    state(DRIVER, 10.01, 0.2)
    io.send_velocity(np.full(7, 0.3))
    state("/spoof", 10.02, 0.9)
    assert io.read_joints().q[0] == pytest.approx(0.2)  # the spoofed state never reached the controller
    assert io.halt_cause == f"second publisher /spoof on {io.hw.joint_state_topic}"
    assert not np.any(io._sent)  # zero went out at once
    io.send_velocity(np.full(7, 0.3))
    io._publish(io._epoch + 0.05)
    assert not np.any(io._sent)  # and stays latched
    report = io.report()
    assert report["halt_cause"] == io.halt_cause and report["ignored_message_causes"]["joint_state"] == {
        "second publisher": 1
    }


def test_the_driver_s_other_inputs_may_have_no_publisher_at_all():
    other = "/j2s7s300_driver/in/cartesian_velocity"
    watch = PublisherWatch(FakeMaster(CLEAN), ME, [CMD, other], [STATE], 0.01, 0.05, [].append)
    watch.snapshot()
    assert watch.findings({**CLEAN, other: ["/teleop"]}) == ["foreign command publisher /teleop"]


def test_the_bridge_s_own_node_shut_down_halts_whatever_the_master_says():
    halts: list[str] = []
    alive = [None]
    watch = PublisherWatch(FakeMaster(CLEAN), ME, [CMD], [STATE], 0.01, 0.05, halts.append, self_check=lambda: alive[0])
    watch.snapshot()
    assert watch.poll_once() is None
    alive[0] = "this node (/tpik_compare_1) was shut down (another node took its name?)"
    assert watch.poll_once() == alive[0] and halts == [alive[0]]

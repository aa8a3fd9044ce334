"""The message checks on hand-made cases (no ROS): stamps, joint states, camera info, service answers."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from compare.hardware.exceptions import HardwareError
from compare.hardware.validation import (
    CameraInfoCheck,
    JointStateCheck,
    MalformedMessage,
    StampCheck,
    check_service_answer,
    header_stamp_s,
)
from compare.sensing.frames import CameraModel

ARM = tuple(f"joint_{i}" for i in range(1, 8))
NAMES = [*ARM, "finger_1", "finger_2"]


def _kind(call) -> str:
    with pytest.raises(MalformedMessage) as exc:
        call()
    return exc.value.kind


def test_stamps_advance_by_about_what_the_arrivals_do_and_a_late_delivery_is_fine():
    check = StampCheck(jump_s=0.5)
    check.check(100.0, 10.0)
    check.accept(100.0, 10.0)
    assert _kind(lambda: check.check(99.999, 10.01)) == "stamp backwards"
    assert _kind(lambda: check.check(100.0, 10.01)) == "stamp repeated"
    assert _kind(lambda: check.check(0.0, 10.01)) == "stamp missing"
    assert _kind(lambda: check.check(100.6, 10.01)) == "stamp jump"  # 0.6 s of stamps in 10 ms
    check.check(102.0, 12.0)  # a 2 s pause in the stream: stamps and arrivals agree
    check.check(100.01, 12.0)  # delivered late (a starved reader): not the stamp's fault
    assert _kind(lambda: check.check(float("nan"), 12.0)) == "bad stamp"


def test_an_unstamped_stream_is_accepted_and_may_start_stamping():
    check = StampCheck()
    for k in range(3):
        check.check(0.0, float(k))
        check.accept(0.0, float(k))
    check.check(1e9, 3.0)


def test_the_first_accepted_joint_names_fix_the_order():
    check = JointStateCheck(ARM)
    q, qdot = check.parse(NAMES, np.arange(9.0), [], 1.0, 1.0)
    np.testing.assert_array_equal(q, np.arange(7.0)) and np.testing.assert_array_equal(qdot, np.zeros(7))
    swapped = [NAMES[1], NAMES[0], *NAMES[2:]]
    assert _kind(lambda: check.parse(swapped, np.arange(9.0), [], 1.01, 1.01)) == "names changed"
    q, _ = check.parse(NAMES, np.arange(9.0) + 1, np.ones(9), 1.02, 1.02)
    assert q[0] == 1.0


@pytest.mark.parametrize(
    ("names", "position", "velocity", "kind"),
    [(NAMES[:6], np.zeros(6), [], "joints missing"),
     ([*NAMES[:8], NAMES[0]], np.zeros(9), [], "duplicate names"),
     (NAMES, np.zeros(8), [], "positions size"),
     (NAMES, [0.0] * 3 + [float("nan")] + [0.0] * 5, [], "position not finite"),
     (NAMES, [0.0] * 6 + [2e3, 0.0, 0.0], [], "position implausible"),
     (NAMES, np.zeros(9), np.zeros(4), "velocities size"),
     (NAMES, np.zeros(9), [float("inf")] + [0.0] * 8, "velocity not finite"),
     (NAMES, ["a"] * 9, [], "positions not numbers")],
)  # fmt: skip
def test_a_malformed_joint_state_is_dropped_with_its_cause(names, position, velocity, kind):
    assert _kind(lambda: JointStateCheck(ARM).parse(names, position, velocity, 1.0, 1.0)) == kind


def test_a_non_finite_finger_does_not_matter():
    position = [0.0] * 7 + [float("nan"), 0.0]
    q, _ = JointStateCheck(ARM).parse(NAMES, position, [], 1.0, 1.0)
    assert np.all(np.isfinite(q))


def _camera(width: int, height: int, K) -> CameraModel:
    return CameraModel(width, height, K[0], K[4], K[2], K[5], np.eye(4))


K = [6.0, 0.0, 3.5, 0.0, 6.0, 2.5, 0.0, 0.0, 1.0]


def test_the_first_camera_info_is_kept_and_a_changed_one_is_dropped():
    check = CameraInfoCheck(_camera)
    cam = check.parse(8, 6, K, "ir", 1.0, 1.0)
    assert check.parse(8, 6, K, "ir", 1.1, 1.1) is cam
    assert _kind(lambda: check.parse(8, 6, [7.0, *K[1:]], "ir", 1.2, 1.2)) == "camera_info changed"
    assert _kind(lambda: check.parse(8, 6, K, "rgb", 1.2, 1.2)) == "camera_info changed"
    assert _kind(lambda: check.parse(9, 6, K, "ir", 1.2, 1.2)) == "camera_info changed"
    assert check.camera is cam and check.frame_id == "ir"


@pytest.mark.parametrize(
    ("width", "height", "k", "kind"),
    [(0, 6, K, "image size"), (8, 100_000, K, "image size"),
     (8, 6, [float("nan"), *K[1:]], "K not finite"), (8, 6, K[:8], "K not finite"),
     (8, 6, [-6.0, *K[1:]], "K not pinhole"), (8, 6, [*K[:8], 0.0], "K not pinhole"),
     (8, 6, [6.0, 0.0, 9.0, *K[3:]], "principal point")],
)  # fmt: skip
def test_a_malformed_camera_info_is_dropped_with_its_cause(width, height, k, kind):
    assert _kind(lambda: CameraInfoCheck(_camera).parse(width, height, k, "ir", 1.0, 1.0)) == kind


def test_a_header_without_a_stamp_is_malformed():
    assert _kind(lambda: header_stamp_s(SimpleNamespace())) == "no header"
    assert header_stamp_s(SimpleNamespace(header=SimpleNamespace(stamp=SimpleNamespace(to_sec=lambda: 2.5)))) == 2.5


class StopResponse:
    _type = "kinova_msgs/StopResponse"

    def __init__(self, stop_result):
        self.stop_result = stop_result


@pytest.mark.parametrize("answer", [None, "Arm stopped", StopResponse(None), StopResponse(b"bytes"), object()])
def test_a_driver_service_answer_must_be_its_response_with_a_text_result(answer):
    with pytest.raises(HardwareError, match="in/stop answered"):
        check_service_answer("in/stop", answer, StopResponse, "stop_result")
    assert check_service_answer("in/stop", StopResponse("Arm stopped"), StopResponse, "stop_result") == "Arm stopped"


@pytest.mark.parametrize(
    "outcome", ["timeout", "driver error", "transport", "deserialization", "socket", "wrong answer", "ok"]
)
def test_every_failure_of_a_service_call_becomes_a_driver_service_error(monkeypatch, outcome):
    """A missing service, a driver error, a broken connection, an answer that does not parse or is not its type."""
    from tests.hardware.conftest import ros_skip_reason

    if ros_skip_reason() is not None:
        pytest.skip(f"ROS 1 not available: {ros_skip_reason()}")
    from compare.config import HardwareConfig
    from compare.hardware.driver_control import DriverServiceError
    from compare.hardware.ros_env import load_ros
    from compare.hardware.ros_io import RosRobotIO

    ros = load_ros()
    rospy = ros.rospy
    import genpy

    io = RosRobotIO(HardwareConfig(joint_names=ARM), np.full(7, 0.6), 0.01, use_depth=False, ros=ros)
    io._services = {"stop": ("/driver/in/stop", ros.Stop)}
    failures = {
        "driver error": rospy.ServiceException("service [/driver/in/stop] responded with an error"),
        "transport": rospy.exceptions.TransportInitError("Unable to connect to service"),
        "deserialization": genpy.DeserializationError("truncated"),
        "socket": ConnectionResetError("reset by peer"),
    }
    answers = {
        "wrong answer": ros.Start._response_class(start_result="x"),
        "ok": ros.Stop._response_class("Arm stopped"),
    }

    def wait_for_service(service, timeout):
        if outcome == "timeout":
            raise rospy.ROSException(f"timeout exceeded while waiting for service {service}")

    def proxy(service, cls):
        def call():
            if outcome in failures:
                raise failures[outcome]
            return answers.get(outcome)

        return call

    monkeypatch.setattr(rospy, "wait_for_service", wait_for_service)
    monkeypatch.setattr(rospy, "ServiceProxy", proxy)
    if outcome == "ok":
        io._call_service("stop")
        return
    with pytest.raises(DriverServiceError, match="/driver/in/stop"):
        io._call_service("stop")

"""Random malformed messages through the stand-in's own message builders into the bridge (hypothesis).

Each example feeds the bridge (:class:`~compare.hardware.ros_io.RosRobotIO`, not connected: its
rospy callbacks are called directly) a valid start (camera info, joint state, depth) and then a
random sequence of messages built by the stand-in (:func:`compare.hardware.standin.joint_state_message`,
:func:`~compare.hardware.standin.depth_messages`), each either valid or broken in one way:
sizes, NaN/inf, encodings, endianness flags, frames, stamps backwards / repeated / missing /
jumping, joint names reordered, renamed, missing or duplicated, camera intrinsics changing, a
second sender. Every message goes through genpy's serialization and back, as rospy delivers it.

After every message: no exception escaped the callback; a valid message was taken, a broken one
was dropped (the controller keeps the last good value) with a cause from the set its breakage
allows, counted in the report; a second sender halted the bridge; the joint state and depth the
controller can read are finite; and the command the stream sends for a finite request is finite
(zero once halted).
"""

from __future__ import annotations

import io as iolib
from dataclasses import dataclass
from typing import Any

import numpy as np
import pytest

from tests.hardware.conftest import ros_skip_reason

pytestmark = [
    pytest.mark.skipif(ros_skip_reason() is not None, reason=f"ROS 1 not available: {ros_skip_reason()}"),
    pytest.mark.slow,  # ~40 s: thousands of examples
]

hypothesis = pytest.importorskip("hypothesis")
st = hypothesis.strategies

EXAMPLES = 2000
ARM = tuple(f"j2s7s300_joint_{i}" for i in range(1, 8))
FINGERS = [f"j2s7s300_joint_finger_{i}" for i in (1, 2, 3)] + [f"j2s7s300_joint_finger_tip_{i}" for i in (1, 2, 3)]
NAMES = list(ARM) + FINGERS  # the driver's 13 names, as the stand-in publishes them
DRIVER = "/j2s7s300_driver"
WALL0 = 1.7e9  # header stamps start here [s]
TOPICS = ("joint_state", "camera_info", "depth")

STAMP_BREAKS = {
    "stamp_back": {"stamp backwards", "stamp missing"},
    "stamp_repeat": {"stamp repeated"},
    "stamp_zero": {"stamp missing"},
    "stamp_jump": {"stamp jump"},
}
BREAKS = {
    "joint_state": {
        "reorder": {"names changed"},
        "rename": {"names changed"},
        "drop_name": {"names changed"},
        "duplicate_name": {"duplicate names"},
        "positions_size": {"positions size"},
        "position_nonfinite": {"position not finite"},
        "position_huge": {"position implausible"},
        "velocity_size": {"velocities size"},
        "velocity_nonfinite": {"velocity not finite"},
        **STAMP_BREAKS,
    },
    "camera_info": {
        "size": {"image size", "principal point", "camera_info changed"},
        "k_nonfinite": {"K not finite"},
        "k_not_pinhole": {"K not pinhole"},
        "principal_point": {"principal point"},
        "k_changed": {"camera_info changed"},
        "frame": {"camera_info changed"},
        **STAMP_BREAKS,
    },
    "depth": {
        "size": {"image size"},
        "encoding": {"encoding"},
        "encoding_swap": {"data size"},
        "endianness": {"is_bigendian"},
        "step": {"data size"},
        "data_size": {"data size"},
        "frame": {"frame"},
        **STAMP_BREAKS,
    },
}
BAD_FLOATS = st.sampled_from([float("nan"), float("inf"), float("-inf")])


@dataclass
class Event:
    """One message of a sequence: its topic, how it is broken (None: valid) and the drawn details."""

    topic: str
    breakage: str | None
    draw: Any


def _events() -> Any:
    def event(topic: str) -> Any:
        breakage = st.one_of(st.none(), st.sampled_from(sorted(BREAKS[topic])))
        return st.builds(Event, st.just(topic), breakage, st.data())

    return st.lists(st.sampled_from(TOPICS).flatmap(event), min_size=1, max_size=10)


@pytest.fixture(scope="module")
def ros():
    from compare.hardware.ros_env import load_ros

    return load_ros()


@pytest.fixture(scope="module")
def camera():
    from compare.sensing.frames import CameraModel

    return CameraModel(width=8, height=6, fx=6.0, fy=6.0, cx=3.5, cy=2.5, transform_base_to_camera=np.eye(4))


def _bridge(camera):
    from compare.config import HardwareConfig
    from compare.hardware.ros_io import RosRobotIO

    hw = HardwareConfig(joint_names=ARM, camera_translation_m=(0.0, 0.0, 0.0), camera_quaternion_xyzw=(0, 0, 0, 1))
    bridge = RosRobotIO(hw, np.full(7, 0.6), 0.01, use_depth=True, dry_run=True)
    bridge.start_clock()
    return bridge


def _wire(msg: Any, caller: str = DRIVER) -> Any | None:
    """The message as rospy delivers it: serialized, deserialized, with its connection header (None: unsendable)."""
    import struct

    from genpy import SerializationError

    buf = iolib.BytesIO()
    try:
        msg.serialize(buf)
    except (struct.error, SerializationError, TypeError, ValueError):
        return None
    out = type(msg)()
    out.deserialize(buf.getvalue())
    out._connection_header = {"callerid": caller, "topic": "?"}
    return out


def _rng(data: Any) -> np.random.Generator:
    """Bulk values (angles, depths) from one drawn seed: cheap to draw, still reproduced by hypothesis."""
    return np.random.default_rng(data.draw(st.integers(0, 2**32 - 1), label="seed"))


def _time(ros, stamp_s: float) -> Any:
    secs = int(stamp_s)
    return ros.rospy.Time(secs, int(round((stamp_s - secs) * 1e9)) % 1_000_000_000)


def _stamp(ros, last: float, breakage: str | None, data: Any) -> Any:
    if breakage == "stamp_back":
        return _time(ros, max(0.0, last - data.draw(st.floats(1e-6, 1e6), label="back_s")))
    if breakage == "stamp_repeat":
        return _time(ros, last)
    if breakage == "stamp_zero":
        return ros.rospy.Time(0, 0)
    if breakage == "stamp_jump":
        return _time(ros, last + data.draw(st.floats(5.0, 1e6), label="jump_s"))
    return _time(ros, last + 0.01)


def _joint_state(ros, breakage: str | None, data: Any, stamp: Any) -> Any:
    from compare.hardware.standin import joint_state_message

    q = _rng(data).uniform(-6.0, 6.0, 7)
    msg = joint_state_message(ros, NAMES, q, stamp)
    names, pos, vel = list(msg.name), list(msg.position), list(msg.velocity)
    n = len(names)
    arm = data.draw(st.integers(0, 6), label="arm_joint")
    if breakage == "reorder":
        i, j = data.draw(st.lists(st.integers(0, n - 1), min_size=2, max_size=2, unique=True), label="swap")
        perm = list(range(n))
        perm[i], perm[j] = j, i
        names, pos, vel = [names[k] for k in perm], [pos[k] for k in perm], [vel[k] for k in perm]
    elif breakage == "rename":
        names[data.draw(st.integers(0, n - 1))] = data.draw(st.text(max_size=20).filter(lambda s: s not in NAMES))
    elif breakage == "drop_name":
        k = data.draw(st.integers(0, n - 1), label="dropped")
        names, pos, vel = names[:k] + names[k + 1 :], pos[:k] + pos[k + 1 :], vel[:k] + vel[k + 1 :]
    elif breakage == "duplicate_name":
        i, j = data.draw(st.lists(st.integers(0, n - 1), min_size=2, max_size=2, unique=True), label="dup")
        names[j] = names[i]
    elif breakage == "positions_size":
        size = data.draw(st.integers(0, 3 * n).filter(lambda k: k != n), label="positions")
        pos = (pos * 3)[:size] if size <= 3 * n else pos
    elif breakage == "position_nonfinite":
        pos[arm] = data.draw(BAD_FLOATS)
    elif breakage == "position_huge":
        pos[arm] = data.draw(st.sampled_from([-1.0, 1.0])) * data.draw(st.floats(1e3 + 1.0, 1e300))
    elif breakage == "velocity_size":
        size = data.draw(st.integers(1, 3 * n).filter(lambda k: k != n), label="velocities")
        vel = (vel * 3)[:size]
    elif breakage == "velocity_nonfinite":
        vel[arm] = data.draw(BAD_FLOATS)
    msg.name, msg.position, msg.velocity = names, pos, vel
    return msg


def _depth_pair(ros, camera, data: Any, stamp: Any, encoding: str | None = None) -> tuple[Any, Any]:
    """A valid (image, camera info) pair, 16UC1 or 32FC1; in 32FC1 some pixels NaN/inf/negative (no return)."""
    from compare.hardware.standin import depth_messages
    from compare.sensing.frames import DepthFrame

    depth = _rng(data).uniform(0.0, 6.0, (6, 8))
    encoding = encoding or data.draw(st.sampled_from(["16UC1", "32FC1"]), label="encoding")
    img, info = depth_messages(ros, DepthFrame(depth.astype(np.float32), 0.0, camera), encoding, stamp)
    if encoding == "32FC1" and data.draw(st.booleans(), label="invalid_pixels"):
        raw = np.frombuffer(img.data, dtype="<f4").copy()
        idx = data.draw(st.lists(st.integers(0, raw.size - 1), min_size=1, max_size=8), label="invalid_idx")
        raw[idx] = data.draw(st.sampled_from([np.nan, np.inf, -np.inf, -1.0]))
        img.data = raw.tobytes()
    return img, info


def _break_camera_info(info: Any, breakage: str | None, data: Any) -> Any:
    k = list(info.K)
    if breakage == "size":
        info.width = data.draw(st.integers(0, 10_000).filter(lambda w: w != 8), label="width")
    elif breakage == "k_nonfinite":
        k[data.draw(st.integers(0, 8))] = data.draw(BAD_FLOATS)
    elif breakage == "k_not_pinhole":
        which = data.draw(st.sampled_from([0, 4, 3, 6, 7, 8]), label="k_entry")
        k[which] = data.draw(st.floats(-10.0, 0.0)) if which in (0, 4) else data.draw(st.floats(0.5, 10.0))
        if which == 8 and k[8] == 1.0:
            k[8] = 2.0
    elif breakage == "principal_point":
        k[2] = data.draw(st.one_of(st.floats(-1e6, -1e-3), st.floats(8.0, 1e6)), label="cx")
    elif breakage == "k_changed":
        k[0] = k[0] * data.draw(st.floats(1.001, 2.0), label="fx_scale")
    elif breakage == "frame":
        info.header.frame_id = data.draw(st.text(max_size=30).filter(lambda s: s != info.header.frame_id))
    info.K = k
    return info


def _break_depth(img: Any, breakage: str | None, data: Any) -> Any:
    from compare.hardware.conversions import DEPTH_ENCODINGS

    if breakage == "size":
        img.width, img.height = data.draw(
            st.tuples(st.integers(0, 100), st.integers(0, 100)).filter(lambda s: s != (8, 6)), label="size"
        )
    elif breakage == "encoding":
        img.encoding = data.draw(
            st.one_of(
                st.sampled_from(["rgb8", "mono8", "16SC1", "32FC2", "16UC3", "bgr8", ""]), st.text(max_size=12)
            ).filter(lambda e: e not in DEPTH_ENCODINGS),
            label="encoding",
        )
    elif breakage == "encoding_swap":  # 16-bit rows read as 32-bit ones (the other way is a padded 16UC1 image)
        img.encoding = "32FC1"
    elif breakage == "endianness":
        img.is_bigendian = data.draw(st.integers(2, 255), label="is_bigendian")
    elif breakage == "step":
        img.step = data.draw(st.integers(0, 4 * img.step).filter(lambda s: s != img.step), label="step")
    elif breakage == "data_size":
        n = len(img.data)
        size = data.draw(st.integers(0, 2 * n).filter(lambda k: k != n), label="bytes")
        img.data = (bytes(img.data) * 2)[:size]
    elif breakage == "frame":
        img.header.frame_id = data.draw(st.text(max_size=30).filter(lambda s: s != img.header.frame_id))
    return img


FED = {"valid": 0, "malformed": 0, "unsendable": 0}
"""Messages fed over the whole module (every example and shrink step)."""


@pytest.fixture(scope="module", autouse=True)
def thousands_fed():
    """The property test fed thousands of malformed messages (checked when the module is done)."""
    yield
    if FED["malformed"] or FED["valid"]:
        print(f"\nfed {FED}")
        assert FED["malformed"] >= 2000, FED


class Oracle:
    """The test's own account: the last valid stamp per topic, what must have happened to each message."""

    def __init__(self) -> None:
        self.last = dict.fromkeys(TOPICS, WALL0)
        self.fed = FED


def _feed(bridge, ros, camera, oracle: Oracle, event: Event) -> None:
    topic, breakage, data = event.topic, event.breakage, event.draw
    stamp = _stamp(ros, oracle.last[topic], breakage, data)
    if topic == "joint_state":
        msg = _joint_state(ros, breakage, data, stamp)
        callback = bridge._on_joint_state
    else:
        img, info = _depth_pair(ros, camera, data, stamp, "16UC1" if breakage == "encoding_swap" else None)
        if topic == "camera_info":
            msg, callback = _break_camera_info(info, breakage, data), bridge._on_camera_info
        else:
            msg, callback = _break_depth(img, breakage, data), bridge._on_depth
    wire = _wire(msg)
    if wire is None:
        oracle.fed["unsendable"] += 1
        return
    before_count = bridge.bad_messages.get(topic, 0)
    before_causes = dict(bridge.bad_causes.get(topic, {}))
    before_state = {"joint_state": bridge._joint, "camera_info": bridge._camera, "depth": bridge._frame}[topic]
    callback(wire)  # nothing may escape
    after_state = {"joint_state": bridge._joint, "camera_info": bridge._camera, "depth": bridge._frame}[topic]
    causes = bridge.bad_causes.get(topic, {})
    if breakage is None:
        oracle.fed["valid"] += 1
        assert bridge.bad_messages.get(topic, 0) == before_count, (topic, causes)
        if topic != "camera_info":  # a valid camera info leaves the camera model as it was
            assert after_state is not before_state
        oracle.last[topic] += 0.01
        return
    oracle.fed["malformed"] += 1
    assert bridge.bad_messages.get(topic, 0) == before_count + 1, (topic, breakage)
    new = {k for k, v in causes.items() if v != before_causes.get(k, 0)}
    assert len(new) == 1 and new <= BREAKS[topic][breakage], (topic, breakage, new)
    assert after_state is before_state  # dropped: the controller keeps the last good value


def _check_outputs(bridge) -> None:
    """What the controller reads is finite; what the stream sends for a finite request is finite."""
    import time

    reading = bridge.read_joints()
    if reading is not None:
        assert reading.q.shape == (7,) and np.all(np.isfinite(reading.q)) and np.all(np.isfinite(reading.qdot))
    frame = bridge.read_depth()
    if frame is not None:
        assert frame.depth_m.shape == (6, 8) and frame.depth_m.dtype == np.float32
        assert np.all(np.isfinite(frame.depth_m)) and np.all(frame.depth_m >= 0.0)
    bridge.send_velocity(np.full(7, 0.2))
    bridge._publish(time.monotonic())
    assert bridge._sent.shape == (7,) and np.all(np.isfinite(bridge._sent))
    if bridge.halt_cause is not None:
        assert not np.any(bridge._sent)


@hypothesis.settings(
    max_examples=EXAMPLES,
    deadline=None,
    database=None,
    suppress_health_check=[hypothesis.HealthCheck.too_slow, hypothesis.HealthCheck.filter_too_much],
)
@hypothesis.given(events=_events(), spoof_at=st.one_of(st.none(), st.integers(0, 9)))
def test_random_malformed_messages_are_dropped_with_their_cause_and_never_reach_the_command(
    ros, camera, events, spoof_at
):
    bridge = _bridge(camera)
    oracle = Oracle()
    for topic in ("camera_info", "joint_state", "depth"):  # a valid start
        stamp = _time(ros, oracle.last[topic])
        if topic == "joint_state":
            from compare.hardware.standin import joint_state_message

            bridge._on_joint_state(_wire(joint_state_message(ros, NAMES, np.zeros(7), stamp)))
        else:
            from compare.hardware.standin import depth_messages
            from compare.sensing.frames import DepthFrame

            img, info = depth_messages(ros, DepthFrame(np.ones((6, 8), np.float32), 0.0, camera), "16UC1", stamp)
            (bridge._on_camera_info if topic == "camera_info" else bridge._on_depth)(
                _wire(info if topic == "camera_info" else img)
            )
    assert bridge.bad_messages == {} and bridge._joint is not None and bridge._frame is not None
    for k, event in enumerate(events):
        if k == spoof_at:  # a valid-looking message from a second publisher
            from compare.hardware.standin import joint_state_message

            stamp = _time(ros, oracle.last["joint_state"] + 0.01)
            before = bridge._joint
            bridge._on_joint_state(_wire(joint_state_message(ros, NAMES, np.full(7, 1.0), stamp), "/spoof"))
            assert bridge._joint is before
            assert bridge.halt_cause == f"second publisher /spoof on {bridge.hw.joint_state_topic}"
        _feed(bridge, ros, camera, oracle, event)
        _check_outputs(bridge)

"""A node that registers as a publisher on one topic and sends nothing (the publisher-watch tests).

``python -m tests.hardware.foreign_publisher TOPIC {JointVelocity,JointState} --record FILE``
writes its caller id and the monotonic times just before and after its registration with the
master (rospy registers inside ``Publisher()``), then stays registered until SIGTERM/SIGINT.
"""

from __future__ import annotations

import argparse
import json
import signal
import sys
import threading
import time
from pathlib import Path

from compare.hardware.ros_env import load_ros
from compare.hardware.ros_io import init_node


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("topic")
    parser.add_argument("type", choices=("JointVelocity", "JointState"))
    parser.add_argument("--record", type=Path, required=True)
    parser.add_argument("--stay-s", type=float, default=60.0)
    args = parser.parse_args(argv)
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    ros = load_ros()
    init_node(ros, "foreign_publisher")
    before = time.monotonic()
    pub = ros.rospy.Publisher(args.topic, getattr(ros, args.type), queue_size=1)
    after = time.monotonic()
    record = {"caller_id": ros.rospy.get_name(), "before_t": before, "registered_t": after}
    args.record.write_text(json.dumps(record), encoding="utf-8")
    stop.wait(args.stay_s)
    pub.unregister()
    ros.rospy.signal_shutdown("done")
    return 0


if __name__ == "__main__":
    sys.exit(main())

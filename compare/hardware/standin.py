"""Driver stand-in: the kinova-ros driver and a Kinect v2 bridge, played by the MuJoCo simulation.

It speaks the real topics and services with the real types and units, and reproduces the
driver's timing with :class:`~compare.hardware.driver_model.KinovaDriverModel`, so
``tpik-compare hw`` can be run and tested end to end without hardware::

    python -m compare.hardware.standin configs/case1.toml --duration 10 --connection usb

* subscribes to ``hardware.velocity_topic`` (``kinova_msgs/JointVelocity``, **deg/s**) and
  serves ``hardware.stop_service`` / ``start_service`` (``kinova_msgs/Stop``, ``Start``); every
  message and call goes through the driver model in real time: one spin thread shared with the
  status timer (nine blocking API calls per status), a subscription queue of one message, the
  arm's 10 ms cycle taking one point per cycle from its trajectory FIFO, ``in/stop`` erasing it;
* each controller cycle steps the simulation (:class:`~compare.loop.sim_io.SimRobotIO`, the
  scenario's scene with the scripted person) by 10 ms with the executed point (zero when the
  FIFO is empty); joint states (``sensor_msgs/JointState``, rad, the driver's 13 names) are
  published when the model's status callback publishes them, with the angles read mid-callback;
* renders the depth camera (robot included, as a real sensor sees it) and publishes
  ``hardware.depth_topic`` (16UC1 mm or 32FC1 m) and ``hardware.camera_info_topic`` at the
  scenario's sensing rate (30 Hz) from its own thread (a snapshot of the simulation);
* ``--connection usb|ethernet`` and ``--feedback-publish-rate`` set the driver's timing (default:
  the config's ``[hardware]``); ``--stop-joint-states-after`` / ``--stop-depth-after`` stop a stream;
* by default the scene clock (the person's script) starts with the first non-zero point the arm
  executes, so the scenario's events happen at the same loop times as in the pure simulation;
* ``--record FILE`` writes what it published, received and executed (times on the shared
  monotonic clock), the service calls and the ground-truth distances, for the tests;
  ``--record-bag FILE`` writes the published joint states, depth and camera info as a ROS bag
  (what ``rosbag record`` gives on the real setup), for ``tpik-compare hw --replay``;
* ``--print-calibration`` prints the ``[hardware]`` camera pose of the simulated camera and exits.

The messages are built by :func:`joint_state_message` and :func:`depth_messages`, which the
tests also use to make valid and malformed messages for the bridge.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

os.environ.setdefault("MUJOCO_GL", "egl")

import mujoco  # noqa: E402

import robots  # noqa: E402
from compare.arguments import (  # noqa: E402
    ArgumentParser,
    existing_file,
    non_negative_float,
    output_path,
    positive_float,
)
from compare.config import Config, ConfigError, load_config  # noqa: E402
from compare.hardware.conversions import (  # noqa: E402
    deg_s_to_rad_s,
    encode_depth,
    translation_quaternion_from_transform,
)
from compare.hardware.driver_model import CONNECTIONS, DriverTiming, KinovaDriverModel, StatePublished  # noqa: E402
from compare.hardware.ros_env import RosApi, load_ros  # noqa: E402
from compare.hardware.ros_io import init_node, master_online  # noqa: E402
from compare.hardware.sensing import save_background  # noqa: E402
from compare.loop.sim_io import SimRobotIO  # noqa: E402
from compare.loop.simulation import build_simulation  # noqa: E402
from compare.scenarios.random_scenario import realize  # noqa: E402
from compare.sensing.camera import camera_model_from_mujoco  # noqa: E402
from compare.sensing.frames import CameraModel, DepthFrame  # noqa: E402
from compare.sensing.pipeline import DepthSensingSettings  # noqa: E402
from compare.sensing.renderer import DepthCamera  # noqa: E402
from compare.sensing.scene import load_workcell, make_data  # noqa: E402

log = logging.getLogger("compare.hardware.standin")

FINGER_NAMES = ("joint_finger_1", "joint_finger_2", "joint_finger_3")
FINGER_TIP_NAMES = ("joint_finger_tip_1", "joint_finger_tip_2", "joint_finger_tip_3")


@dataclass
class World:
    """The simulated arm, its scene and camera, as the stand-in drives them.

    Attributes:
        io: Simulated arm (stepped one controller cycle per :meth:`SimRobotIO.wait`).
        render_depth: Depth frame of a simulation state (robot included); None = no camera.
        truth: Ground-truth obstacle distance per control point [m]; None = unknown.
        camera: The camera's intrinsics and pose (base frame).
        close: Releases the renderer.
    """

    io: SimRobotIO
    render_depth: Callable[[mujoco.MjData], DepthFrame] | None
    truth: Callable[[robots.Kinematics], Mapping[str, float]] | None
    camera: CameraModel | None
    close: Callable[[], None]


def build_world(config: Config, robot: robots.Robot) -> World:
    """The scenario's simulation (scene, scripted person, raw depth camera) for the stand-in."""
    sc = config.scenario
    q0 = np.array(sc.start_q) if sc.start_q is not None else robot.home.copy()
    sim = build_simulation(config, robot, q0)
    io = sim.io
    if sim.pipeline is not None:  # depth mode: its camera renders the raw frames (arm included)
        renderer = sim.pipeline.renderer
        own = False
    else:
        settings = DepthSensingSettings.from_sensor_config(config.sensor, seed=sc.seed)
        renderer = DepthCamera(io.model, settings.camera, noise=settings.noise, seed=sc.seed)
        own = True

    def close() -> None:
        if own:
            renderer.close()
        sim.close()

    return World(io=io, render_depth=renderer.render, truth=sim.truth, camera=renderer.camera, close=close)


def camera_calibration() -> dict[str, list[float]]:
    """The ``[hardware]`` camera pose of the work cell's camera: what a perfect calibration gives."""
    model = load_workcell()
    t, q = translation_quaternion_from_transform(camera_model_from_mujoco(model).transform_base_to_camera)
    return {"camera_translation_m": list(t), "camera_quaternion_xyzw": list(q)}


def write_background(path: Path) -> None:
    """Save the work cell's static scene as a background file: what a perfect capture gives."""
    model = load_workcell()
    camera = DepthCamera(model)
    try:
        save_background(path, camera.render_static(make_data(model)))
    finally:
        camera.close()


DEPTH_FRAME_ID = "kinect2_ir_optical_frame"
"""Frame of the stand-in's depth image and camera info (the Kinect v2 bridge's)."""


def joint_state_message(ros: RosApi, names: list[str], q: np.ndarray, stamp: Any) -> Any:
    """The driver's ``sensor_msgs/JointState``: ``q`` [rad] for the first ``len(q)`` names, 0 for the fingers."""
    msg = ros.JointState()
    msg.header.stamp = stamp
    msg.name = list(names)
    extra = len(names) - len(q)
    msg.position = [float(v) for v in q] + [0.0] * extra
    msg.velocity = [0.0] * len(names)
    msg.effort = [0.0] * len(names)
    return msg


def depth_messages(ros: RosApi, frame: DepthFrame, encoding: str, stamp: Any) -> tuple[Any, Any]:
    """The Kinect v2 bridge's ``sensor_msgs/Image`` (depth in ``encoding``) and ``sensor_msgs/CameraInfo``."""
    cam = frame.camera
    img = ros.Image()
    img.header.stamp = stamp
    img.header.frame_id = DEPTH_FRAME_ID
    img.height, img.width = cam.height, cam.width
    img.encoding = encoding
    img.is_bigendian = 0
    img.step, img.data = encode_depth(frame.depth_m, encoding)
    info = ros.CameraInfo()
    info.header = img.header
    info.height, info.width = cam.height, cam.width
    info.distortion_model = "plumb_bob"
    info.D = [0.0] * 5
    info.K = [cam.fx, 0.0, cam.cx, 0.0, cam.fy, cam.cy, 0.0, 0.0, 1.0]
    info.R = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
    info.P = [cam.fx, 0.0, cam.cx, 0.0, 0.0, cam.fy, cam.cy, 0.0, 0.0, 0.0, 1.0, 0.0]
    return img, info


class StandIn:
    """The stand-in node: the driver model in real time, the simulation as the arm, the camera.

    Args:
        config: Scenario and ``[hardware]`` topics/services.
        world: The simulation to drive.
        ros: Loaded ROS API.
        timing: The driver's timing (connection, ``feedback_publish_rate``, API call durations).
        encoding: Depth encoding published (``16UC1`` or ``32FC1``).
        wait_for_motion: Start the scene clock at the first non-zero point executed.
        stop_joint_states_after_s: Scene time after which joint states stop [s] (None: never).
        stop_depth_after_s: Scene time after which depth and camera info stop [s] (None: never).
        seed: Seed of the driver model's call durations.
        bag: Write the published streams to this ROS bag.
    """

    def __init__(
        self,
        config: Config,
        world: World,
        ros: RosApi,
        timing: DriverTiming,
        encoding: str = "16UC1",
        wait_for_motion: bool = True,
        stop_joint_states_after_s: float | None = None,
        stop_depth_after_s: float | None = None,
        seed: int = 0,
        bag: Path | None = None,
    ) -> None:
        self.config = config
        self.hw = config.hardware
        self.world = world
        self.ros = ros
        self.timing = timing
        self.encoding = encoding
        self.wait_for_motion = wait_for_motion
        self.stop_joint_states_after_s = stop_joint_states_after_s
        self.stop_depth_after_s = stop_depth_after_s
        self.nq = len(self.hw.joint_names)
        self.depth_period_s = 1.0 / config.scenario.sensing_rate_hz
        prefix = self.hw.joint_names[0].rsplit("joint_", 1)[0]
        self.names = list(self.hw.joint_names) + [prefix + n for n in FINGER_NAMES + FINGER_TIP_NAMES]
        self._robot = config.load_robot()
        self._sim_lock = threading.Lock()  # the simulation (stepped by the controller cycle, copied by the camera)
        self._model_lock = threading.Lock()  # the driver model (fed by rospy threads, run by the driver thread)
        self._wake = threading.Event()
        self._stop = threading.Event()
        self.scene_t = 0.0
        self.started_t: float | None = None
        self.model = KinovaDriverModel(
            timing, self._apply_point, self._read_q, t0=time.monotonic(), seed=seed, on_state=self._on_state
        )
        self.record: dict[str, list[Any]] = {
            "command_t": [],
            "command_deg_s": [],
            "joint_state_t": [],
            "depth_t": [],
            "scene_t": [],
            "q": [],
            "overruns": [],
            "truth_t": [],  # monotonic time of each ground-truth sample [s]
            "truth_m": [],  # ground-truth obstacle distance per control point [m]
        }
        self.truth_min: dict[str, float] = {}
        self._snapshot = mujoco.MjData(world.io.model) if world.render_depth is not None else None
        self._bag: Any = None
        self._bag_lock = threading.Lock()
        self._bag_path = bag
        self._pub_state: Any = None
        self._pub_depth: Any = None
        self._pub_info: Any = None

    def stop(self) -> None:
        """Ask the main loop to end (signal-safe)."""
        self._stop.set()
        self._wake.set()

    # -- driver model <-> simulation (called under the model lock) ------------------------

    def _apply_point(self, t: float, deg_s: np.ndarray | None) -> None:
        """One 10 ms controller cycle with the executed point (None: FIFO empty or arm stopped)."""
        if self.started_t is None:
            if not self.wait_for_motion or (deg_s is not None and np.any(deg_s)):
                self.started_t = t
            else:
                return  # the scene waits for the first motion (the person's script with it)
        command = deg_s_to_rad_s(deg_s) if deg_s is not None else np.zeros(self.nq)
        io = self.world.io
        with self._sim_lock:
            io.send_velocity(command)
            io.wait()
            self.scene_t += io.dt
            q = io.read_joints().q
        if self.world.truth is not None:
            distances = self.world.truth(self._robot.kinematics(q))
            for cp, d in distances.items():
                self.truth_min[cp] = min(self.truth_min.get(cp, math.inf), float(d))
            self.record["truth_t"].append(time.monotonic())
            self.record["truth_m"].append({cp: float(d) for cp, d in distances.items()})
        self.record["scene_t"].append(self.scene_t)
        self.record["q"].append(q.tolist())

    def _read_q(self) -> np.ndarray:
        with self._sim_lock:
            return self.world.io.read_joints().q

    def _on_state(self, state: StatePublished) -> None:
        if self.stop_joint_states_after_s is not None and self.scene_t >= self.stop_joint_states_after_s:
            return
        self._publish_state(state.q)
        self.record["joint_state_t"].append(time.monotonic())

    # -- ROS callbacks (rospy threads) -----------------------------------------------------

    def _on_command(self, msg: Any) -> None:
        now = time.monotonic()
        deg_s = [msg.joint1, msg.joint2, msg.joint3, msg.joint4, msg.joint5, msg.joint6, msg.joint7]
        with self._model_lock:
            self.model.receive_velocity(now, deg_s)
            self.record["command_t"].append(now)
            self.record["command_deg_s"].append(list(deg_s))
        self._wake.set()

    def _serve(self, name: str) -> Any:
        with self._model_lock:
            ticket = self.model.request_service(time.monotonic(), name)
        self._wake.set()
        if not ticket.done.wait(10.0):
            raise self.ros.rospy.ServiceException(f"in/{name}: the driver model did not answer")
        log.info("in/%s served in %.1f ms", name, 1e3 * (ticket.done_t - ticket.requested_t))  # type: ignore[operator]
        return ticket

    def _on_stop(self, _request: Any) -> Any:
        self._serve("stop")
        return self.ros.Stop._response_class(stop_result="Arm stopped")

    def _on_start(self, _request: Any) -> Any:
        self._serve("start")
        return self.ros.Start._response_class(start_result="Arm started")

    # -- threads ---------------------------------------------------------------------------

    def _driver_loop(self) -> None:
        """The driver model in real time: run its events as the wall clock reaches them."""
        while not self._stop.is_set():
            now = time.monotonic()
            with self._model_lock:
                late = now - self.model.next_event_t()
                self.model.advance(now)
                nxt = self.model.next_event_t()
            if late > 0.02:
                self.record["overruns"].append(now)
            self._wake.clear()
            self._wake.wait(min(max(0.0, nxt - time.monotonic()), 0.005))

    def run(self, duration_s: float) -> None:
        """Serve the driver and the camera until ``duration_s`` of scene time or :meth:`stop`."""
        rospy, ros = self.ros.rospy, self.ros
        self._pub_state = rospy.Publisher(self.hw.joint_state_topic, ros.JointState, queue_size=10)
        if self.world.render_depth is not None:
            self._pub_depth = rospy.Publisher(self.hw.depth_topic, ros.Image, queue_size=2)
            self._pub_info = rospy.Publisher(self.hw.camera_info_topic, ros.CameraInfo, queue_size=2)
        if self._bag_path is not None:
            import rosbag  # Deferred: ROS 1 is optional, importable only after load_ros()

            self._bag = rosbag.Bag(str(self._bag_path), "w")
        # Like the driver (roscpp, default hints): no TCP_NODELAY requested. The model is the
        # subscription queue (size 1): rospy's own queue just hands every message over.
        sub = rospy.Subscriber(self.hw.velocity_topic, ros.JointVelocity, self._on_command, queue_size=100)
        services = [
            rospy.Service(self.hw.stop_service, ros.Stop, self._on_stop),
            rospy.Service(self.hw.start_service, ros.Start, self._on_start),
        ]
        driver = threading.Thread(target=self._driver_loop, name="driver-model", daemon=True)
        with self._model_lock:
            self.model.advance(time.monotonic())
        driver.start()
        log.info("stand-in running: %s (%s)", self.hw.joint_state_topic, self.timing.connection)
        next_depth = time.monotonic()
        try:
            while not self._stop.is_set() and self.scene_t < duration_s:
                now = time.monotonic()
                if self.world.render_depth is not None and now >= next_depth:
                    next_depth = max(next_depth + self.depth_period_s, now - self.depth_period_s)
                    if self.stop_depth_after_s is None or self.scene_t < self.stop_depth_after_s:
                        self._publish_depth(*self._render())
                        self.record["depth_t"].append(time.monotonic())
                self._stop.wait(max(0.0, min(next_depth - time.monotonic(), 0.05)))
        finally:
            self._stop.set()
            self._wake.set()
            driver.join(timeout=5.0)
            sub.unregister()
            for srv in services:
                srv.shutdown()
            if self._bag is not None:
                with self._bag_lock:
                    self._bag.close()
                    self._bag = None

    def _render(self) -> tuple[DepthFrame, Any]:
        """The camera's view of the scene now, and its header stamp: the moment the scene was copied.

        The stamp is taken under the simulation lock with the copy (a camera stamps its exposure):
        taken before the lock, a thread kept waiting for it would stamp a scene older than the
        one it renders, and the bridge would self-filter the arm where it had been.
        """
        assert self.world.render_depth is not None and self._snapshot is not None
        with self._sim_lock:
            taken = self.ros.rospy.Time.now()
            mujoco.mj_copyData(self._snapshot, self.world.io.model, self.world.io.data)
        return self.world.render_depth(self._snapshot), taken

    def _write_bag(self, topic: str, msg: Any, stamp: Any) -> None:
        if self._bag is None:
            return
        with self._bag_lock:
            if self._bag is not None:
                self._bag.write(topic, msg, stamp)

    def _publish_state(self, q: np.ndarray) -> None:
        msg = joint_state_message(self.ros, self.names, q, self.ros.rospy.Time.now())
        self._pub_state.publish(msg)
        self._write_bag(self.hw.joint_state_topic, msg, msg.header.stamp)

    def _publish_depth(self, frame: DepthFrame, stamp: Any) -> None:
        img, info = depth_messages(self.ros, frame, self.encoding, stamp)
        self._pub_info.publish(info)
        self._pub_depth.publish(img)
        self._write_bag(self.hw.camera_info_topic, info, stamp)
        self._write_bag(self.hw.depth_topic, img, stamp)

    def write_record(self, path: Path) -> None:
        """Write the record as JSON (times on the monotonic clock shared with ``tpik-compare hw``)."""
        with self._model_lock:
            m = self.model
            data: dict[str, Any] = dict(self.record)
            data["commands"] = [
                {"arrival_t": c.arrival_t, "outcome": c.outcome, "executed_t": c.executed_t, "deg_s": c.deg_s.tolist()}
                for c in m.commands
            ]
            data["services"] = [{"name": t.name, "requested_t": t.requested_t, "done_t": t.done_t} for t in m.services]
            data["state_sample_t"] = [s.sample_t for s in m.states]
            data["state_model_t"] = [s.t for s in m.states]
            data["fifo_peak"] = m.fifo_peak
            data["cycles"] = m.cycles
        data["connection"] = self.timing.connection
        data["status_interval_s"] = self.timing.status_interval_s
        data["started_t"] = self.started_t
        data["depth_period_s"] = self.depth_period_s
        data["truth_min_m"] = self.truth_min
        data["stop_joint_states_after_s"] = self.stop_joint_states_after_s
        data["stop_depth_after_s"] = self.stop_depth_after_s
        path.write_text(json.dumps(data), encoding="utf-8")


def _parser() -> ArgumentParser:
    """The stand-in's options (module docstring)."""
    parser = ArgumentParser(
        prog="python -m compare.hardware.standin",
        description=__doc__.split("\n")[0] + "\n\nServes the driver's topics and services and the depth camera "
        "from the scenario's simulation\nin real time (needs a ROS master); see docs/hardware.md.",
    )
    parser.add_argument("config", type=existing_file, help="scenario TOML (scene, person, [hardware] topics and rates)")
    parser.add_argument(
        "--duration",
        metavar="S",
        type=positive_float,
        default=None,
        help="scene time to run [s] (default: the scenario's)",
    )
    parser.add_argument(
        "--time-scale",
        metavar="X",
        type=positive_float,
        default=None,
        help="override scenario.time_scale (default: the scenario's)",
    )
    parser.add_argument(
        "--connection", choices=CONNECTIONS, default=None, help="driver connection (default: hardware.connection_type)"
    )
    parser.add_argument(
        "--feedback-publish-rate",
        metavar="S",
        type=positive_float,
        default=None,
        help="the driver's status interval [s] (default: hardware.feedback_publish_rate_s)",
    )
    parser.add_argument(
        "--api-call-ms",
        type=non_negative_float,
        nargs=2,
        metavar=("BASE", "SPREAD"),
        default=None,
        help="duration of one blocking API call: BASE + Exp(SPREAD) [ms] (default: the connection's)",
    )
    parser.add_argument("--seed", type=int, default=0, help="seed of the API call durations")
    parser.add_argument(
        "--stop-joint-states-after",
        metavar="S",
        type=non_negative_float,
        default=None,
        help="stop the joint states at this scene time [s]",
    )
    parser.add_argument(
        "--stop-depth-after",
        metavar="S",
        type=non_negative_float,
        default=None,
        help="stop the depth stream at this scene time [s]",
    )
    parser.add_argument(
        "--encoding", choices=("16UC1", "32FC1"), default="16UC1", help="depth encoding: 16UC1 [mm] or 32FC1 [m]"
    )
    parser.add_argument("--no-wait-for-motion", action="store_true", help="start the scene clock at once")
    parser.add_argument("--no-depth", action="store_true", help="publish no camera")
    parser.add_argument(
        "--record", metavar="FILE", type=output_path, default=None, help="write a JSON record here at the end"
    )
    parser.add_argument(
        "--record-bag", metavar="FILE", type=output_path, default=None, help="write the published streams to this bag"
    )
    parser.add_argument("--print-calibration", action="store_true", help="print the [hardware] camera pose; exit")
    parser.add_argument(
        "--write-background",
        metavar="FILE",
        type=output_path,
        default=None,
        help="save the static scene's depth (background file); exit",
    )
    return parser


def main(argv: list[str] | None = None) -> int:
    """Command-line entry point (``python -m compare.hardware.standin``)."""
    parser = _parser()
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    # A stop asked for while the scene is still being built (e.g. the bridge refused its start at
    # once) is remembered and honoured as soon as the node exists, so the record is still written.
    early_stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: early_stop.set())
    overrides: dict[str, object] = {}
    if args.time_scale is not None:
        overrides["scenario.time_scale"] = args.time_scale
    try:
        config, _ = load_config(args.config, overrides)
    except ConfigError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    robot = config.load_robot()
    config = realize(config, robot)
    if args.print_calibration:
        print(json.dumps(camera_calibration()))
        return 0
    if args.write_background is not None:
        write_background(args.write_background)
        return 0
    hw = config.hardware
    timing = DriverTiming.for_connection(
        args.connection or hw.connection_type,
        args.feedback_publish_rate if args.feedback_publish_rate is not None else hw.feedback_publish_rate_s,
    )
    if args.api_call_ms is not None:
        base_ms, spread_ms = args.api_call_ms
        timing = dataclasses.replace(timing, call_base_s=base_ms * 1e-3, call_spread_s=spread_ms * 1e-3)
    ros = load_ros()
    uri = ros.rosgraph.get_master_uri()
    if not master_online(uri, 2.0):
        print(f"error: no ROS master at {uri}", file=sys.stderr)
        return 2
    world = build_world(config, robot)
    if args.no_depth:
        world.render_depth = None
    init_node(ros, "j2s7s300_driver_standin")
    node = StandIn(
        config,
        world,
        ros,
        timing,
        encoding=args.encoding,
        wait_for_motion=not args.no_wait_for_motion,
        stop_joint_states_after_s=args.stop_joint_states_after,
        stop_depth_after_s=args.stop_depth_after,
        seed=args.seed,
        bag=args.record_bag,
    )
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: node.stop())
    if early_stop.is_set():
        node.stop()
    duration = args.duration if args.duration is not None else config.scenario.sim_time_s
    try:
        node.run(duration)
    finally:
        if args.record is not None:
            node.write_record(args.record)
        world.close()
        ros.rospy.signal_shutdown("stand-in done")
    return 0


if __name__ == "__main__":
    sys.exit(main())

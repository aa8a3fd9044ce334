"""Driver stand-in: the kinova-ros driver and a Kinect v2 bridge, played by the MuJoCo simulation.

It speaks the real topics with the real types and units, so ``tpik-compare hw`` can be run and
tested end to end without hardware::

    python -m compare.hardware.standin configs/case1.toml --duration 10

* subscribes to ``hardware.velocity_topic`` (``kinova_msgs/JointVelocity``, **deg/s**); a command
  is held for ``--hold-s`` (the real arm stops when the stream stops);
* steps the simulation (:class:`~compare.loop.sim_io.SimRobotIO`, the scenario's scene with the scripted
  person) in real time and publishes ``hardware.joint_state_topic`` (``sensor_msgs/JointState``,
  rad, the driver's 13 names: 7 arm joints, 3 fingers, 3 finger tips) at ``hardware.state_rate_hz``;
* renders the depth camera (robot included, as a real sensor sees it) and publishes
  ``hardware.depth_topic`` (16UC1 mm or 32FC1 m) and ``hardware.camera_info_topic`` at the
  scenario's sensing rate (30 Hz);
* ``--stop-joint-states-after`` / ``--stop-depth-after`` stop either stream (watchdog tests);
* by default the scene clock (the person's script) starts with the first non-zero command, so
  the scenario's events happen at the same loop times as in the pure simulation;
* ``--record FILE`` writes what it published and received (times on the shared monotonic clock)
  and the ground-truth distances, for the tests;
* ``--print-calibration`` prints the ``[hardware]`` camera pose of the simulated camera and exits.
"""

from __future__ import annotations

import argparse
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

import robots  # noqa: E402
from compare.campaign.random_scenario import realize  # noqa: E402
from compare.config import Config, ConfigError, load_config  # noqa: E402
from compare.hardware.conversions import (  # noqa: E402
    deg_s_to_rad_s,
    encode_depth,
    translation_quaternion_from_transform,
)
from compare.hardware.ros_env import RosApi, load_ros  # noqa: E402
from compare.hardware.ros_io import init_node, master_online  # noqa: E402
from compare.loop.robot_io import CameraModel, DepthFrame  # noqa: E402
from compare.loop.sim_io import SimRobotIO  # noqa: E402

log = logging.getLogger("compare.hardware.standin")

FINGER_NAMES = ("joint_finger_1", "joint_finger_2", "joint_finger_3")
FINGER_TIP_NAMES = ("joint_finger_tip_1", "joint_finger_tip_2", "joint_finger_tip_3")


@dataclass
class World:
    """The simulated arm, its scene and camera, as the stand-in drives them.

    Attributes:
        io: Simulated arm (stepped one period per :meth:`SimRobotIO.wait`).
        render_depth: Depth frame of the current state (robot included); None = no camera.
        truth: Ground-truth obstacle distance per control point [m]; None = unknown.
        camera: The camera's intrinsics and pose (base frame).
        close: Releases the renderer.
    """

    io: SimRobotIO
    render_depth: Callable[[], DepthFrame] | None
    truth: Callable[[robots.Kinematics], Mapping[str, float]] | None
    camera: CameraModel | None
    close: Callable[[], None]


def build_world(config: Config, robot: robots.Robot) -> World:
    """The scenario's simulation (scene, scripted person, raw depth camera) for the stand-in."""
    from compare.loop.simulation import build_simulation

    sc = config.scenario
    q0 = np.array(sc.start_q) if sc.start_q is not None else robot.home.copy()
    sim = build_simulation(config, robot, q0)
    io = sim.io
    if sim.pipeline is not None:  # depth mode: its camera renders the raw frames (arm included)
        renderer = sim.pipeline.renderer
        own = False
    else:
        from compare.sensing.pipeline import DepthSensingSettings
        from compare.sensing.renderer import DepthCamera

        settings = DepthSensingSettings.from_sensor_config(config.sensor, seed=sc.seed)
        renderer = DepthCamera(io.model, settings.camera, noise=settings.noise, seed=sc.seed)
        own = True

    def render() -> DepthFrame:
        return renderer.render(io.data)

    def close() -> None:
        if own:
            renderer.close()
        sim.close()

    return World(io=io, render_depth=render, truth=sim.truth, camera=renderer.camera, close=close)


def camera_calibration() -> dict[str, list[float]]:
    """The ``[hardware]`` camera pose of the work cell's camera: what a perfect calibration gives."""
    from compare.sensing.camera import camera_model_from_mujoco
    from compare.sensing.scene import load_workcell

    model = load_workcell()
    t, q = translation_quaternion_from_transform(camera_model_from_mujoco(model).transform_base_to_camera)
    return {"camera_translation_m": list(t), "camera_quaternion_xyzw": list(q)}


def write_background(path: Path) -> None:
    """Save the work cell's static scene as a background file: what a perfect capture gives."""
    from compare.hardware.sensing import save_background
    from compare.sensing.renderer import DepthCamera
    from compare.sensing.scene import load_workcell, make_data

    model = load_workcell()
    camera = DepthCamera(model)
    try:
        save_background(path, camera.render_static(make_data(model)))
    finally:
        camera.close()


class StandIn:
    """The stand-in node.

    Args:
        config: Scenario and ``[hardware]`` topics/rates.
        world: The simulation to drive.
        ros: Loaded ROS API.
        encoding: Depth encoding published (``16UC1`` or ``32FC1``).
        hold_s: How long a velocity command is applied without a newer one [s].
        wait_for_motion: Start the scene clock at the first non-zero command.
        stop_joint_states_after_s: Scene time after which joint states stop [s] (None: never).
        stop_depth_after_s: Scene time after which depth and camera info stop [s] (None: never).
    """

    def __init__(
        self,
        config: Config,
        world: World,
        ros: RosApi,
        encoding: str = "16UC1",
        hold_s: float = 0.03,
        wait_for_motion: bool = True,
        stop_joint_states_after_s: float | None = None,
        stop_depth_after_s: float | None = None,
    ) -> None:
        self.config = config
        self.hw = config.hardware
        self.world = world
        self.ros = ros
        self.encoding = encoding
        self.hold_s = hold_s
        self.wait_for_motion = wait_for_motion
        self.stop_joint_states_after_s = stop_joint_states_after_s
        self.stop_depth_after_s = stop_depth_after_s
        self.nq = len(self.hw.joint_names)
        self.period_s = 1.0 / self.hw.state_rate_hz
        self.depth_period_s = 1.0 / config.scenario.sensing_rate_hz
        prefix = self.hw.joint_names[0].rsplit("joint_", 1)[0]
        self.names = list(self.hw.joint_names) + [prefix + n for n in FINGER_NAMES + FINGER_TIP_NAMES]
        self._lock = threading.Lock()
        self._command = np.zeros(self.nq)
        self._command_t = -math.inf
        self._stop = threading.Event()
        self.started_t: float | None = None
        self.record: dict[str, list[Any]] = {
            "command_t": [],
            "command_deg_s": [],
            "joint_state_t": [],
            "depth_t": [],
            "scene_t": [],
            "q": [],
            "overruns": [],
        }
        self.truth_min: dict[str, float] = {}
        self._pub_state: Any = None
        self._pub_depth: Any = None
        self._pub_info: Any = None

    def stop(self) -> None:
        """Ask the main loop to end (signal-safe)."""
        self._stop.set()

    def _on_command(self, msg: Any) -> None:
        now = time.monotonic()
        deg_s = np.array([msg.joint1, msg.joint2, msg.joint3, msg.joint4, msg.joint5, msg.joint6, msg.joint7])
        with self._lock:
            self._command = deg_s_to_rad_s(deg_s)
            self._command_t = now
            self.record["command_t"].append(now)
            self.record["command_deg_s"].append(deg_s.tolist())
            if self.started_t is None and np.any(deg_s):
                self.started_t = now

    def run(self, duration_s: float) -> None:
        """Publish and simulate until ``duration_s`` of scene time or :meth:`stop`."""
        rospy, ros = self.ros.rospy, self.ros
        self._pub_state = rospy.Publisher(self.hw.joint_state_topic, ros.JointState, queue_size=10)
        if self.world.render_depth is not None:
            self._pub_depth = rospy.Publisher(self.hw.depth_topic, ros.Image, queue_size=2)
            self._pub_info = rospy.Publisher(self.hw.camera_info_topic, ros.CameraInfo, queue_size=2)
        # Like the driver (roscpp, default hints): no TCP_NODELAY requested.
        sub = rospy.Subscriber(self.hw.velocity_topic, ros.JointVelocity, self._on_command, queue_size=10)
        io = self.world.io
        robot = self.config.load_robot()
        tick = time.monotonic()
        next_depth_scene_t = 0.0
        last_depth_wall = -math.inf
        scene_t = 0.0
        log.info("stand-in running: %s", self.hw.joint_state_topic)
        try:
            while not self._stop.is_set() and scene_t < duration_s:
                now = time.monotonic()
                running = self.started_t is not None or not self.wait_for_motion
                with self._lock:
                    fresh = now - self._command_t <= self.hold_s
                    command = self._command.copy() if fresh else np.zeros(self.nq)
                if running:
                    io.send_velocity(command)
                    io.wait()
                    scene_t += io.dt
                    if self.world.truth is not None:
                        kin = robot.kinematics(io.read_joints().q)
                        for cp, d in self.world.truth(kin).items():
                            self.truth_min[cp] = min(self.truth_min.get(cp, math.inf), float(d))
                reading = io.read_joints()
                if self.stop_joint_states_after_s is None or scene_t < self.stop_joint_states_after_s:
                    self._publish_state(reading.q, reading.qdot)
                    self.record["joint_state_t"].append(time.monotonic())
                self.record["scene_t"].append(scene_t)
                self.record["q"].append(reading.q.tolist())
                if self.world.render_depth is not None:
                    if running:
                        due = scene_t + 1e-9 >= next_depth_scene_t
                        if due:
                            next_depth_scene_t = max(next_depth_scene_t + self.depth_period_s, scene_t)
                    else:  # before the start: 30 Hz on the wall clock
                        due = now - last_depth_wall >= self.depth_period_s
                    if due:
                        last_depth_wall = now
                        if self.stop_depth_after_s is None or scene_t < self.stop_depth_after_s:
                            self._publish_depth(self.world.render_depth())
                            self.record["depth_t"].append(time.monotonic())
                tick += self.period_s
                delay = tick - time.monotonic()
                if delay > 0:
                    time.sleep(delay)
                elif -delay > self.period_s:
                    self.record["overruns"].append(time.monotonic())
                    tick = time.monotonic()
        finally:
            sub.unregister()

    def _publish_state(self, q: np.ndarray, qdot: np.ndarray) -> None:
        msg = self.ros.JointState()
        msg.header.stamp = self.ros.rospy.Time.now()
        msg.name = self.names
        extra = len(self.names) - self.nq
        msg.position = [float(v) for v in q] + [0.0] * extra
        msg.velocity = [float(v) for v in qdot] + [0.0] * extra
        msg.effort = [0.0] * len(self.names)
        self._pub_state.publish(msg)

    def _publish_depth(self, frame: DepthFrame) -> None:
        cam = frame.camera
        stamp = self.ros.rospy.Time.now()
        img = self.ros.Image()
        img.header.stamp = stamp
        img.header.frame_id = "kinect2_ir_optical_frame"
        img.height, img.width = cam.height, cam.width
        img.encoding = self.encoding
        img.is_bigendian = 0
        img.step, img.data = encode_depth(frame.depth_m, self.encoding)
        info = self.ros.CameraInfo()
        info.header = img.header
        info.height, info.width = cam.height, cam.width
        info.distortion_model = "plumb_bob"
        info.D = [0.0] * 5
        info.K = [cam.fx, 0.0, cam.cx, 0.0, cam.fy, cam.cy, 0.0, 0.0, 1.0]
        info.R = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
        info.P = [cam.fx, 0.0, cam.cx, 0.0, 0.0, cam.fy, cam.cy, 0.0, 0.0, 0.0, 1.0, 0.0]
        self._pub_info.publish(info)
        self._pub_depth.publish(img)

    def write_record(self, path: Path) -> None:
        """Write the record as JSON."""
        data = dict(self.record)
        data["started_t"] = self.started_t
        data["period_s"] = self.period_s
        data["depth_period_s"] = self.depth_period_s
        data["truth_min_m"] = self.truth_min
        data["stop_joint_states_after_s"] = self.stop_joint_states_after_s
        data["stop_depth_after_s"] = self.stop_depth_after_s
        path.write_text(json.dumps(data), encoding="utf-8")


def main(argv: list[str] | None = None) -> int:
    """Command-line entry point (``python -m compare.hardware.standin``)."""
    parser = argparse.ArgumentParser(prog="python -m compare.hardware.standin", description=__doc__.split("\n")[0])
    parser.add_argument("config", type=Path, help="Scenario TOML (scene, person, [hardware] topics and rates).")
    parser.add_argument("--duration", type=float, default=None, help="Scene time to run [s] (default: the scenario's).")
    parser.add_argument("--time-scale", type=float, default=None, help="Override scenario.time_scale.")
    parser.add_argument("--stop-joint-states-after", type=float, default=None, help="Scene time [s].")
    parser.add_argument("--stop-depth-after", type=float, default=None, help="Scene time [s].")
    parser.add_argument("--encoding", choices=("16UC1", "32FC1"), default="16UC1")
    parser.add_argument("--hold-s", type=float, default=0.03, help="Command hold time [s].")
    parser.add_argument("--no-wait-for-motion", action="store_true", help="Start the scene clock at once.")
    parser.add_argument("--no-depth", action="store_true", help="Publish no camera.")
    parser.add_argument("--record", type=Path, default=None, help="Write a JSON record here at the end.")
    parser.add_argument("--print-calibration", action="store_true", help="Print the [hardware] camera pose; exit.")
    parser.add_argument(
        "--write-background", type=Path, default=None, help="Save the static scene's depth (background file); exit."
    )
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
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
        encoding=args.encoding,
        hold_s=args.hold_s,
        wait_for_motion=not args.no_wait_for_motion,
        stop_joint_states_after_s=args.stop_joint_states_after,
        stop_depth_after_s=args.stop_depth_after,
    )
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: node.stop())
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

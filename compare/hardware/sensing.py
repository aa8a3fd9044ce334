"""Obstacle distance from the real depth camera: the simulation's sensing pieces on ROS frames.

The simulation's :class:`~compare.sensing.pipeline.DepthPipeline` renders its frames and its
background from the MuJoCo scene; on hardware the frames come from ROS, the camera model from
``camera_info`` plus the calibrated pose, and the background from live frames at start. The
filters and the distance are the same classes with the same settings
(:class:`~compare.sensing.pipeline.DepthSensingSettings` from ``[sensor]``).

Per update (30 Hz, called by the control loop): take the latest frame; if it is new, remove the
static scene (:class:`~compare.sensing.self_filter.StaticBackground`) and the arm
(:class:`~compare.sensing.self_filter.SelfFilter`, swept from the joint positions known when the
frame was taken to the newest ones: :func:`self_filter_poses`); then run the depth-space distance
(:class:`~compare.sensing.depth_distance.DepthDistance`) for the control points at the current
joint positions. Unlike the simulation's source, a frame older than ``[sensor] max_age_s`` is
reported *blind* (a stalled camera must stop the arm, not replay its last frame).
"""

from __future__ import annotations

import logging
import math
import time
import warnings
from collections.abc import Callable
from pathlib import Path

import numpy as np

from compare.config import Config
from compare.hardware.exceptions import HardwareError
from compare.loop.closed_loop import control_points
from compare.sensing.camera import valid_fraction
from compare.sensing.depth_distance import DepthDistance
from compare.sensing.frames import CameraModel, DepthFrame
from compare.sensing.pipeline import DepthSensingSettings
from compare.sensing.results import DistanceResult, ObstacleReading
from compare.sensing.scene import control_point_positions
from compare.sensing.self_filter import SelfFilter, StaticBackground
from robots import Kinematics, Robot

log = logging.getLogger(__name__)


def sensing_settings(config: Config) -> DepthSensingSettings:
    """The simulation's depth-sensing parameters from ``[sensor]`` (noise = the real sensor's, for the margins)."""
    return DepthSensingSettings.from_sensor_config(config.sensor, seed=config.scenario.seed)


def make_self_filter(robot: Robot, camera: CameraModel, settings: DepthSensingSettings) -> SelfFilter:
    """Arm removal on the arm's own model (its visual geoms), for frames of ``camera``."""
    return SelfFilter(
        robot.mj_model,
        camera,
        margin_m=settings.self_filter_margin_m,
        noise=settings.noise,
        noise_allowance=settings.noise_allowance,
        root_body=settings.robot_root_body or robot.base_body,
    )


SWEEP_STEP_RAD = 0.02
"""Largest joint step [rad] between the poses the self-filter removes (:func:`self_filter_poses`)."""
SWEEP_MAX_POSES = 8
"""At most this many poses per frame (a longer gap is spanned with larger steps)."""


def self_filter_poses(
    q_frame: np.ndarray | None, q_now: np.ndarray, q_ahead: np.ndarray | None = None
) -> list[np.ndarray]:
    """Arm poses whose pixels the self-filter removes from one live frame.

    The joint state that had arrived when the frame was taken (``q_frame``) was measured some
    milliseconds before it (the driver's sampling, the transport; more on a loaded computer), and
    ``q_now`` (the newest state, at the loop's time) usually after it: the arm in the image lies
    between the two. When no state newer than the frame has arrived yet (a 45 Hz USB state stream
    against 30 Hz frames), the arm in the image is already past ``q_now``: ``q_ahead``
    (:meth:`~compare.hardware.ros_io.RosRobotIO.frame_q_ahead`, the newest state extrapolated
    with the velocity sent) bounds it. Removing only one pose leaves part of a fast-moving arm in
    the frame, and that part reads as an obstacle a few centimetres from its own control points
    (a *phantom*: 0.04 m on link 7 seen at load ~5 in ``tests/hardware``). So the arm is removed
    along the path q_frame → q_now → q_ahead, at poses at most :data:`SWEEP_STEP_RAD` apart per
    joint: its swept volume over the latency, inflated by the filter's margin. (A person point
    inside that volume is hidden for the frame; the sweep lasts one frame's latency.)

    Args:
        q_frame: Joint positions when the frame was taken (None: unknown, ``q_now`` only) [rad].
        q_now: The newest joint positions [rad].
        q_ahead: Where the arm may already have been past ``q_now`` (None: not beyond it) [rad].

    Returns:
        The poses, ``q_frame`` first; at most :data:`SWEEP_MAX_POSES` (a long path gets larger steps).
    """
    if q_frame is None:
        q_frame = q_now
    anchors = [q_frame, q_now] + ([] if q_ahead is None else [q_ahead])
    lengths = [float(np.max(np.abs(b - a))) for a, b in zip(anchors[:-1], anchors[1:], strict=True)]
    steps = [int(np.ceil(length / SWEEP_STEP_RAD)) for length in lengths]
    budget = SWEEP_MAX_POSES - 1
    if sum(steps) > budget:  # share the poses by length, at least one per moving segment
        total = sum(lengths)
        steps = [max(1, int(budget * length / total)) if length > 0 else 0 for length in lengths]
    poses = [q_frame]
    for a, b, n in zip(anchors[:-1], anchors[1:], steps, strict=True):
        poses.extend(a + (b - a) * (k / n) for k in range(1, n + 1))
    return poses


class HardwareDepthSensing:
    """An :class:`~compare.loop.closed_loop.ObstacleSource` on live depth frames.

    Args:
        robot: The arm model (its visual geoms are what the self-filter removes).
        camera: Camera model of the frames (intrinsics from ``camera_info``, calibrated pose).
        frames: Latest frame (``RosRobotIO.read_depth``), stamps on the loop's clock.
        q_at: Measured joint positions [rad] at a time on the same clock (None if unknown).
        config: ``[sensor]`` margins, noise, ρ, blind fraction and max age.
        background: Static scene to remove (None: keep everything the self-filter leaves).
        q_ahead: Where the arm may already have been past the newest joint state when a frame
            was taken (:func:`self_filter_poses`; None: not extrapolated).
    """

    def __init__(
        self,
        robot: Robot,
        camera: CameraModel,
        frames: Callable[[], DepthFrame | None],
        q_at: Callable[[float], np.ndarray | None],
        config: Config,
        background: StaticBackground | None = None,
        q_ahead: Callable[[float], np.ndarray | None] | None = None,
    ) -> None:
        s = self.settings = sensing_settings(config)
        self.self_filter = make_self_filter(robot, camera, s)
        self.control_points = control_points(config.build_hierarchy(robot), robot)
        self.distance = DepthDistance(camera, s.rho_m, s.blind_fraction, s.min_support)
        self.background = background
        self.camera = camera
        self.max_age_s = config.sensor.max_age_s
        self._frames = frames
        self._q_at = q_at
        self._q_ahead = q_ahead
        self._last: tuple[DepthFrame, DepthFrame, float] | None = None
        self.filter_time_s = 0.0

    def update(self, t: float, kin: Kinematics) -> DistanceResult:
        """Closest obstacle of every control point at loop time ``t`` [s] with the arm at ``kin.q``."""
        frame = self._frames()
        if frame is None or t - frame.stamp_s > self.max_age_s:
            return DistanceResult({n: ObstacleReading.nothing() for n in self.control_points}, 0.0, True, t)
        if self._last is not None and self._last[0] is frame:
            filtered, vf = self._last[1], self._last[2]
        else:
            start = time.perf_counter()
            vf = valid_fraction(frame)
            q = self._q_at(frame.stamp_s)
            depth = np.nan_to_num(frame.depth_m, nan=0.0, posinf=0.0, neginf=0.0).astype(np.float32, copy=True)
            if self.background is not None:
                self.background.apply_inplace(depth)
            ahead = None if self._q_ahead is None else self._q_ahead(frame.stamp_s)
            for pose in self_filter_poses(q, kin.q, ahead):
                self.self_filter.apply_inplace(depth, q=pose)
            filtered = DepthFrame(depth, frame.stamp_s, frame.camera)
            self._last = (frame, filtered, vf)
            self.filter_time_s = time.perf_counter() - start
        return self.distance.compute(filtered, control_point_positions(kin, self.control_points), vf)


def capture_background(
    frames: Callable[[], DepthFrame | None],
    q_at: Callable[[float], np.ndarray | None],
    robot: Robot,
    config: Config,
    duration_s: float,
) -> np.ndarray | None:
    """Depth of the static scene from live frames (nobody may be in view), the arm left out.

    Every frame is self-filtered with the joint positions measured when it arrived; the
    background of a pixel is the median of its arm-free valid returns, provided it had one in at
    least half of the frames where the arm did not hide it. Pixels the arm hid in every frame get
    no background (0: anything seen there later is kept, conservatively — move the arm during the
    capture to uncover them, or load a background file).

    Returns:
        Background depth [m], float32 (H, W), 0 = none; None if ``duration_s`` <= 0 or no frame came.
    """
    if duration_s <= 0.0:
        return None
    settings = sensing_settings(config)
    filters: dict[int, SelfFilter] = {}
    stack: list[np.ndarray] = []
    seen: list[np.ndarray] = []
    last_stamp = -math.inf
    end = time.monotonic() + duration_s
    while time.monotonic() < end:
        frame = frames()
        if frame is not None and frame.stamp_s > last_stamp:
            last_stamp = frame.stamp_s
            depth = np.nan_to_num(frame.depth_m, nan=0.0, posinf=0.0, neginf=0.0).astype(np.float32)
            valid = depth > 0.0
            q = q_at(frame.stamp_s)
            if q is not None:
                key = id(frame.camera)
                if key not in filters:
                    filters[key] = make_self_filter(robot, frame.camera, settings)
                filters[key].apply_inplace(depth, q=q)
            arm = valid & (depth <= 0.0)  # returns the self-filter removed
            stack.append(depth)
            seen.append(~arm)
        time.sleep(0.005)
    if not stack:
        return None
    depth = np.stack(stack)
    unhidden = np.stack(seen)
    valid = depth > 0.0
    with warnings.catch_warnings():  # pixels never valid: all-NaN columns, handled by `keep`
        warnings.simplefilter("ignore", RuntimeWarning)
        median = np.nanmedian(np.where(valid, depth, np.nan), axis=0)
    n_unhidden = unhidden.sum(axis=0)
    keep = (n_unhidden > 0) & (valid.sum(axis=0) >= 0.5 * n_unhidden)
    background = np.where(keep & np.isfinite(median), median, 0.0).astype(np.float32)
    log.info("background captured from %d frames (%.0f%% pixels)", len(stack), 100.0 * float(np.mean(background > 0)))
    return background


def static_background(depth_m: np.ndarray, config: Config) -> StaticBackground:
    """The static-scene filter for a background depth image, with the simulation's margins."""
    settings = sensing_settings(config)
    margin, noise, allowance = settings.background_margin_m, settings.noise, settings.noise_allowance
    return StaticBackground(depth_m, margin_m=margin, noise=noise, noise_allowance=allowance)


def save_background(path: Path, depth_m: np.ndarray) -> None:
    """Write a background depth image [m] (0 = none) to an ``.npz`` file."""
    np.savez_compressed(Path(path), depth_m=np.asarray(depth_m, dtype=np.float32))


def load_background(path: Path, camera: CameraModel) -> np.ndarray:
    """Read a background written by :func:`save_background`; its size must match ``camera``.

    Raises:
        HardwareError: unreadable file or a size different from the camera's.
    """
    try:
        with np.load(Path(path)) as data:
            depth = np.asarray(data["depth_m"], dtype=np.float32)
    except (OSError, KeyError, ValueError) as exc:
        raise HardwareError(f"background file {path}: cannot read ({exc})") from None
    if depth.shape != (camera.height, camera.width):
        raise HardwareError(
            f"background file {path} is {depth.shape[1]}x{depth.shape[0]} px, the camera {camera.width}x{camera.height}"
        )
    return depth

"""Scenario configuration: TOML → validated, typed objects (DESIGN §7).

Every mistake a user can make in a config file (unknown key, wrong type, impossible
threshold, unknown method or QP solver, bad solver setting) becomes one :class:`ConfigError`
whose message names the key, e.g. ``scenario.duration_s: Input should be greater than 0``.
"""

from __future__ import annotations

import math
import tomllib
from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

import robots
from tpik.exceptions import TpikError
from tpik.hierarchy import Hierarchy


class ConfigError(ValueError):
    """A configuration problem, with the offending key in the message."""


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


Vec3 = tuple[float, float, float]


class ScenarioConfig(_Strict):
    """What is simulated and for how long.

    Attributes:
        name: Scenario name written to ``summary.json``.
        kind: ``case1`` / ``case2`` (scripted, the paper) or ``random`` (drawn from ``seed``).
        duration_s: Simulated time [s], before ``time_scale``.
        time_scale: Multiplies every event time and the duration (a short form keeps the events).
        control_rate_hz: Control loop rate (paper: 100 Hz).
        sensing_rate_hz: Depth/distance update rate (paper: 30 Hz, the Kinect's).
        sensing: ``depth`` (rendered depth + self-filter + depth-space distance) or ``geometric``
            (closest points from the MuJoCo geometry; fast, for sweeps; labelled in results).
        simulation: ``dynamic`` (MuJoCo physics, velocity servos with gravity compensation) or
            ``kinematic`` (q integrated from the command).
        seed: Seed of every random draw (random scenario, sensor noise).
        start_q: Start configuration [rad]; default the model's ``home`` keyframe.
        fallback: What the loop commands when a solver fails: ``zero`` or ``hold_last``
            (the last safe command, decayed to zero over ``fallback_decay_s``).
        fallback_decay_s: Decay time of ``hold_last`` [s].
    """

    name: str = "scenario"
    kind: Literal["case1", "case2", "random"] = "case1"
    duration_s: float = Field(70.0, gt=0.0)
    time_scale: float = Field(1.0, gt=0.0, le=10.0)
    control_rate_hz: float = Field(100.0, gt=0.0, le=2000.0)
    sensing_rate_hz: float = Field(30.0, gt=0.0, le=1000.0)
    sensing: Literal["depth", "geometric"] = "depth"
    simulation: Literal["dynamic", "kinematic"] = "dynamic"
    seed: int = Field(0, ge=0)
    start_q: tuple[float, float, float, float, float, float, float] | None = None
    fallback: Literal["zero", "hold_last"] = "zero"
    fallback_decay_s: float = Field(0.2, gt=0.0)

    @property
    def sim_time_s(self) -> float:
        """Simulated duration after scaling [s]."""
        return self.duration_s * self.time_scale

    @property
    def dt(self) -> float:
        """Control period [s]."""
        return 1.0 / self.control_rate_hz


class WaypointsConfig(_Strict):
    """End-effector targets in the base frame.

    Attributes:
        positions: Waypoints [m]; empty = hold the start position (case 2).
        tolerance_m: Distance at which a waypoint counts as reached [m].
        dwell_s: Time spent at a reached waypoint before the next (scaled by time_scale) [s].
        cycle: Go back to the first waypoint after the last (case 1 alternates p¹, p²).
    """

    positions: list[Vec3] = Field(default_factory=list)
    tolerance_m: float = Field(0.02, gt=0.0)
    dwell_s: float = Field(2.0, ge=0.0)
    cycle: bool = True


class PersonKeyframe(_Strict):
    """Person pose at time ``t`` (linearly interpolated between keyframes).

    Attributes:
        t: Time [s] (scaled by time_scale).
        position: Torso position on the floor (x, y) in the base frame [m].
        yaw: Heading [rad] (0 = facing +x).
        right_hand: Right hand target [m] (base frame); None = arm hanging.
        left_hand: Left hand target [m]; None = arm hanging.
    """

    t: float = Field(ge=0.0)
    position: tuple[float, float]
    yaw: float = 0.0
    right_hand: Vec3 | None = None
    left_hand: Vec3 | None = None


class PersonConfig(_Strict):
    """The person's scripted trajectory; no keyframes = nobody in the scene."""

    keyframes: list[PersonKeyframe] = Field(default_factory=list)

    @field_validator("keyframes")
    @classmethod
    def _increasing(cls, frames: list[PersonKeyframe]) -> list[PersonKeyframe]:
        times = [f.t for f in frames]
        if any(b <= a for a, b in zip(times, times[1:], strict=False)):
            raise ValueError(f"keyframe times must increase strictly, got {times}")
        return frames


class SensorConfig(_Strict):
    """Simulated depth camera and distance estimation.

    Attributes:
        noise_std_m: Gaussian depth noise σ [m].
        dropout: Fraction of pixels without return (set to 0), in [0, 1).
        rho_m: Half side of each control point's surveillance cube [m].
        self_filter_margin_m: Inflation of the robot geometry removed from the image [m].
        blind_fraction: Valid-pixel fraction under which a frame is "blind" (safe stop).
        max_age_s: Distance estimate older than this → stale → safe stop [s].
    """

    noise_std_m: float = Field(0.0, ge=0.0, le=0.5)
    dropout: float = Field(0.0, ge=0.0, lt=1.0)
    rho_m: float = Field(0.5, gt=0.0, le=2.0)
    self_filter_margin_m: float = Field(0.03, ge=0.0, le=0.3)
    blind_fraction: float = Field(0.3, ge=0.0, le=1.0)
    max_age_s: float = Field(0.2, gt=0.0)


class RandomConfig(_Strict):
    """Ranges of the ``random`` scenario family (all drawn from ``scenario.seed``).

    Attributes:
        waypoints: Number of waypoints drawn inside ``workspace_lower``/``upper``.
        workspace_lower: Box for waypoints [m].
        workspace_upper: Box for waypoints [m].
        start_perturbation_rad: Uniform perturbation of the home pose [rad].
        person_speed_mps: Range of the person's walking speed [m/s].
        person_visits: Number of approaches to the arm.
        noise_std_m: Range of depth noise σ [m].
        dropout: Range of pixel dropout fraction.
    """

    waypoints: int = Field(3, ge=1, le=20)
    workspace_lower: Vec3 = (-0.45, -0.45, 0.25)
    workspace_upper: Vec3 = (0.45, 0.45, 0.85)
    start_perturbation_rad: float = Field(0.3, ge=0.0, le=math.pi)
    person_speed_mps: tuple[float, float] = (0.3, 1.2)
    person_visits: int = Field(2, ge=0, le=20)
    noise_std_m: tuple[float, float] = (0.0, 0.01)
    dropout: tuple[float, float] = (0.0, 0.05)


class LevelConfig(_Strict):
    """One priority level; task tables are checked by :meth:`tpik.Hierarchy.from_description`."""

    name: str
    tasks: list[dict[str, Any]] = Field(min_length=1)


class MethodsConfig(_Strict):
    """Which methods run, and their settings by method name.

    Attributes:
        names: Method names (``tpik``, ``tpik-ss``, ``hqp-<qp solver>``, ``mink``).
        settings: ``{method name: {setting: value}}`` passed to the method.
    """

    names: list[str] = Field(default_factory=lambda: ["tpik", "hqp-daqp", "mink"], min_length=1)
    settings: dict[str, dict[str, Any]] = Field(default_factory=dict)

    @model_validator(mode="after")
    def _settings_for_named_methods(self) -> MethodsConfig:
        for key in self.settings:
            if key not in self.names:
                raise ValueError(f"settings for '{key}', which is not in names {self.names}")
        return self


Vec4 = tuple[float, float, float, float]


class HardwareConfig(_Strict):
    """The real Jaco² and depth camera through ROS 1 (``tpik-compare hw``, docs/hardware.md).

    Topics default to the kinova-ros driver of a j2s7s300 and a Kinect v2 bridge. Rates are
    those the driver is launched with: ``state_rate_hz`` = 1 / ``feedback_publish_rate``.

    Attributes:
        node_name: ROS node name of the controller.
        joint_state_topic: ``sensor_msgs/JointState`` from the driver (positions in rad).
        velocity_topic: ``kinova_msgs/JointVelocity`` to the driver (deg/s, 100 Hz).
        joint_names: Names of the 7 arm joints in the joint state, in model order.
        depth_topic: ``sensor_msgs/Image`` depth (16UC1 in mm or 32FC1 in m).
        camera_info_topic: ``sensor_msgs/CameraInfo`` of the depth image.
        state_rate_hz: Joint state rate the driver was launched with [Hz]; sets the watchdog.
        min_state_rate_fraction: Start refuses if the measured state rate is below this
            fraction of ``state_rate_hz``.
        state_timeout_periods: Watchdog: no joint state for this many state periods → zero velocity.
        depth_timeout_s: Watchdog: no depth frame for this long → zero velocity [s].
        max_velocity_scale: Fraction of the model's joint velocity limits allowed on hardware.
        max_acceleration_rad_s2: Clamp on the change of the commanded velocity [rad/s²].
        camera_translation_m: Optical-frame origin in the arm base frame [m] (calibrated).
        camera_quaternion_xyzw: Optical-frame orientation in the base frame, (x, y, z, w) as
            ``tf``/``static_transform_publisher`` print it. Both or neither; missing → no start.
        depth_min_range_m: Closest valid depth [m].
        depth_max_range_m: Farthest valid depth [m].
        use_depth: Use the depth camera (required when the hierarchy has obstacle tasks).
        background_file: Background depth image of the static scene (``.npz`` written by
            ``tpik-compare hw --capture-background``); when set, no capture at start.
        background_capture_s: Otherwise, time spent at start capturing the static scene (table,
            floor) from live frames, removed from every later frame; nobody may be in view [s].
            0 = no background removal.
        startup_timeout_s: Time to wait for the first joint state, camera info and depth [s].
    """

    node_name: str = "tpik_compare"
    joint_state_topic: str = "/j2s7s300_driver/out/joint_state"
    velocity_topic: str = "/j2s7s300_driver/in/joint_velocity"
    joint_names: tuple[str, str, str, str, str, str, str] = tuple(  # type: ignore[assignment]
        f"j2s7s300_joint_{i}" for i in range(1, 8)
    )
    depth_topic: str = "/kinect2/sd/image_depth_rect"
    camera_info_topic: str = "/kinect2/sd/camera_info"
    state_rate_hz: float = Field(100.0, gt=0.0, le=1000.0)
    min_state_rate_fraction: float = Field(0.8, ge=0.0, le=1.0)
    state_timeout_periods: float = Field(3.0, ge=1.0, le=100.0)
    depth_timeout_s: float = Field(0.2, gt=0.0, le=5.0)
    max_velocity_scale: float = Field(1.0, gt=0.0, le=1.0)
    max_acceleration_rad_s2: float = Field(4.0, gt=0.0, le=100.0)
    camera_translation_m: Vec3 | None = None
    camera_quaternion_xyzw: Vec4 | None = None
    depth_min_range_m: float = Field(0.5, ge=0.0)
    depth_max_range_m: float = Field(4.5, gt=0.0)
    use_depth: bool = True
    background_file: str | None = None
    background_capture_s: float = Field(1.0, ge=0.0, le=30.0)
    startup_timeout_s: float = Field(5.0, gt=0.0, le=120.0)

    @field_validator("joint_names")
    @classmethod
    def _unique_names(cls, names: tuple[str, ...]) -> tuple[str, ...]:
        if len(set(names)) != len(names):
            raise ValueError(f"joint names must be unique, got {list(names)}")
        return names

    @field_validator("camera_quaternion_xyzw")
    @classmethod
    def _unit_quaternion(cls, quat: Vec4 | None) -> Vec4 | None:
        if quat is None:
            return None
        norm = math.sqrt(sum(v * v for v in quat))
        if not math.isfinite(norm) or abs(norm - 1.0) > 1e-3:
            raise ValueError(f"quaternion must have unit norm (got norm {norm:.6g})")
        return (quat[0] / norm, quat[1] / norm, quat[2] / norm, quat[3] / norm)

    @model_validator(mode="after")
    def _camera_pair(self) -> HardwareConfig:
        if (self.camera_translation_m is None) != (self.camera_quaternion_xyzw is None):
            raise ValueError("give both camera_translation_m and camera_quaternion_xyzw, or neither")
        if self.depth_max_range_m <= self.depth_min_range_m:
            raise ValueError("depth_max_range_m must be > depth_min_range_m")
        return self

    @property
    def state_timeout_s(self) -> float:
        """Joint-state watchdog timeout [s]: ``state_timeout_periods`` state periods."""
        return self.state_timeout_periods / self.state_rate_hz

    @property
    def has_camera_transform(self) -> bool:
        """Whether the calibrated camera pose is given."""
        return self.camera_translation_m is not None and self.camera_quaternion_xyzw is not None


class Config(_Strict):
    """A whole scenario file."""

    scenario: ScenarioConfig = Field(default_factory=ScenarioConfig)
    waypoints: WaypointsConfig = Field(default_factory=WaypointsConfig)
    person: PersonConfig = Field(default_factory=PersonConfig)
    sensor: SensorConfig = Field(default_factory=SensorConfig)
    random: RandomConfig = Field(default_factory=RandomConfig)
    levels: list[LevelConfig] = Field(min_length=1)
    methods: MethodsConfig = Field(default_factory=MethodsConfig)
    hardware: HardwareConfig = Field(default_factory=HardwareConfig)

    def hierarchy_description(self) -> list[dict[str, Any]]:
        """The levels as the plain description :meth:`Hierarchy.from_description` takes."""
        return [{"name": lv.name, "tasks": [dict(t) for t in lv.tasks]} for lv in self.levels]

    def build_hierarchy(self, robot: robots.Robot) -> Hierarchy:
        """A fresh hierarchy (each method gets its own: tasks carry targets and obstacles)."""
        return Hierarchy.from_description(self.hierarchy_description(), robot)


def _format_validation_error(exc: ValidationError) -> str:
    err = exc.errors()[0]
    loc = ".".join(str(p) if not isinstance(p, int) else f"[{p}]" for p in err["loc"]).replace(".[", "[")
    msg = err["msg"]
    if err["type"] == "extra_forbidden":
        msg = "unknown key"
    return f"{loc}: {msg}" if loc else msg


def parse_config(data: dict[str, Any], robot: robots.Robot | None = None) -> Config:
    """Validate a config mapping, including the hierarchy and the methods.

    Raises:
        ConfigError: one line naming the key.
    """
    try:
        config = Config.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(_format_validation_error(exc)) from None
    robot = robot or robots.load("jaco2")
    try:
        config.build_hierarchy(robot)
    except TpikError as exc:
        raise ConfigError(f"levels: {exc}") from None
    except robots.RobotError as exc:
        raise ConfigError(f"levels: {exc}") from None
    _check_methods(config, robot)
    return config


def _check_methods(config: Config, robot: robots.Robot) -> None:
    from compare.methods import UnknownMethod, make_method

    for i, name in enumerate(config.methods.names):
        try:
            make_method(name, robot, config.methods.settings.get(name))
        except UnknownMethod as exc:
            raise ConfigError(f"methods.names[{i}]: {exc}") from None
        except (TypeError, ValueError, KeyError) as exc:
            raise ConfigError(f"methods.settings.{name}: {exc}") from None
        except Exception as exc:  # a backend's own error type for a bad setting
            raise ConfigError(f"methods.settings.{name}: {type(exc).__name__}: {exc}") from None


def load_config(path: str | Path, overrides: dict[str, Any] | None = None) -> tuple[Config, str]:
    """Read and validate a TOML config file; returns the config and the file's text.

    Args:
        path: TOML file.
        overrides: Dotted keys replacing values, e.g. ``{"scenario.time_scale": 0.25}``.

    Raises:
        ConfigError: unreadable file, TOML syntax error, or any validation error.
    """
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as exc:
        raise ConfigError(f"{p}: cannot read config ({exc.strerror})") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{p}: invalid TOML: {exc}") from None
    for dotted, value in (overrides or {}).items():
        node = data
        *parents, leaf = dotted.split(".")
        for key in parents:
            node = node.setdefault(key, {})
        node[leaf] = value
    return parse_config(data), text

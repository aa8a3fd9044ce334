"""Scenario configuration: TOML → validated, typed objects (docs/design.md §7).

Every mistake a user can make in a config file (unknown key, wrong type, impossible
threshold, unknown method or QP solver, bad solver setting) becomes one :class:`ConfigError`
whose message names the key, e.g. ``scenario.duration_s: Input should be greater than 0``.
"""

from __future__ import annotations

import hashlib
import importlib
import importlib.util
import math
import re
import sys
import tomllib
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType
from typing import Any, Literal

import tomli_w
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

import robots
from compare.exceptions import CompareError
from compare.sensing.motion_estimate import MotionFilterSettings
from compare.sensing.prediction import PredictionSettings
from compare.sensing.rig import scene_camera_names
from qp_baseline.exceptions import HqpError
from qp_baseline.hqp import available_qp_solvers
from tpik.exceptions import TpikError
from tpik.hierarchy import Hierarchy
from tpik.tasks import ObstacleDistanceTask


class ConfigError(CompareError, ValueError):
    """A configuration problem, with the offending key in the message."""


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


Vec3 = tuple[float, float, float]


class ScenarioConfig(_Strict):
    """What is simulated and for how long.

    Attributes:
        name: Scenario name written to ``summary.json``.
        robot: Registry name of the arm (:func:`robots.available_robots`: ``jaco2``, ``panda``,
            ``ur5``, or one added with :func:`robots.register`).
        kind: ``case1`` / ``case2`` (scripted, the paper), ``random`` (drawn from ``seed``) or
            ``scripted`` (any other fixed scenario, e.g. a random draw frozen as a file).
        duration_s: Simulated time [s], before ``time_scale``.
        time_scale: Multiplies every event time and the duration (a short form keeps the events).
        control_rate_hz: Control loop rate (paper: 100 Hz).
        sensing_rate_hz: Depth/distance update rate (paper: 30 Hz, the Kinect's).
        sensing: ``depth`` (rendered depth + self-filter + depth-space distance) or ``geometric``
            (closest points from the MuJoCo geometry; fast, for sweeps; labelled in results).
        simulation: ``dynamic`` (MuJoCo physics, joint drives with gravity compensation) or
            ``kinematic`` (q integrated from the command).
        drive: Joint drive of ``dynamic`` simulation (:mod:`compare.loop.joint_drive`): ``decoupled``
            (inverse dynamics, every joint a first-order lag 1/λ) or ``servo`` (the MJCF's P-only
            velocity servos, coupled and slightly slow).
        drive_bandwidth_rad_s: λ of the ``decoupled`` drive [rad/s] (100: a 10 ms lag; at most
            250, i.e. λ·h ≤ 0.5 with the model's 2 ms physics step).
        seed: Seed of every random draw (random scenario, sensor noise).
        start_q: Start configuration [rad], one value per joint of ``robot``; default its home pose.
        fallback: What the loop commands when a solver fails: ``zero`` or ``hold_last``
            (the last safe command, decayed to zero over ``fallback_decay_s``).
        fallback_decay_s: Decay time of ``hold_last`` [s].
    """

    name: str = "scenario"
    robot: str = robots.DEFAULT_ROBOT
    kind: Literal["case1", "case2", "random", "scripted"] = "case1"
    duration_s: float = Field(70.0, gt=0.0)
    time_scale: float = Field(1.0, gt=0.0, le=10.0)
    control_rate_hz: float = Field(100.0, gt=0.0, le=2000.0)
    sensing_rate_hz: float = Field(30.0, gt=0.0, le=1000.0)
    sensing: Literal["depth", "geometric"] = "depth"
    simulation: Literal["dynamic", "kinematic"] = "dynamic"
    drive: Literal["decoupled", "servo"] = "decoupled"
    drive_bandwidth_rad_s: float = Field(100.0, gt=0.0, le=250.0)
    seed: int = Field(0, ge=0)
    start_q: tuple[float, ...] | None = None
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
    """The person's scripted trajectory; no keyframes = nobody in the scene.

    Attributes:
        keyframes: Poses over time (``[[person.keyframes]]`` tables), linearly interpolated.
    """

    keyframes: list[PersonKeyframe] = Field(default_factory=list)

    @field_validator("keyframes")
    @classmethod
    def _increasing(cls, frames: list[PersonKeyframe]) -> list[PersonKeyframe]:
        times = [f.t for f in frames]
        if any(b <= a for a, b in zip(times, times[1:], strict=False)):
            raise ValueError(f"keyframe times must increase strictly, got {times}")
        return frames


class CameraConfig(_Strict):
    """One depth camera of ``[[sensor.cameras]]`` (``compare.sensing.rig``; docs/design.md §4).

    A camera named like one of the scene's (``depth_camera``) keeps every value the MJCF gives
    and overrides only what is set here; any other name adds a camera to the scene and needs
    ``position_m`` plus ``look_at_m`` or ``quaternion_xyzw``; its intrinsics default to the
    Kinect v2 depth stream (512×424, f = 365.5 px, c = (255, 205) px, 0.5–4.5 m).

    Attributes:
        name: Camera name (the scene's, or a new one).
        position_m: Optical centre in the base frame [m].
        look_at_m: A point on the optical axis [m] (image x kept horizontal).
        quaternion_xyzw: Orientation of the optical frame (x right, y down, z forward) in the
            base frame, (x, y, z, w) as ``tf`` prints it (a calibrated pose); instead of ``look_at_m``.
        resolution: (width, height) [px].
        focal_px: (fx, fy) [px].
        principal_px: (cx, cy) [px].
        range_m: Valid depth range (min, max) [m].
        rate_hz: Frame rate [Hz]; default ``scenario.sensing_rate_hz``. Not slower than that rate
            (a frame must be new at every distance update, or the loop's stale-frame check stops the arm).
        noise_std_m: Gaussian depth noise σ [m]; default ``[sensor] noise_std_m``.
        dropout: Fraction of pixels without return; default ``[sensor] dropout``.
        self_filter_margin_m: Inflation of the arm removed from this camera's images [m]; default
            ``[sensor] self_filter_margin_m``.
    """

    name: str = Field(min_length=1)
    position_m: Vec3 | None = None
    look_at_m: Vec3 | None = None
    quaternion_xyzw: tuple[float, float, float, float] | None = None
    resolution: tuple[int, int] | None = None
    focal_px: tuple[float, float] | None = None
    principal_px: tuple[float, float] | None = None
    range_m: tuple[float, float] | None = None
    rate_hz: float | None = Field(None, gt=0.0, le=1000.0)
    noise_std_m: float | None = Field(None, ge=0.0, le=0.5)
    dropout: float | None = Field(None, ge=0.0, lt=1.0)
    self_filter_margin_m: float | None = Field(None, ge=0.0, le=0.3)

    @model_validator(mode="after")
    def _pose_and_intrinsics(self) -> CameraConfig:
        if self.look_at_m is not None and self.quaternion_xyzw is not None:
            raise ValueError("give look_at_m or quaternion_xyzw, not both")
        if (self.position_m is None) != (self.look_at_m is None and self.quaternion_xyzw is None):
            raise ValueError("give position_m together with look_at_m or quaternion_xyzw")
        if self.position_m is not None and self.look_at_m is not None:
            if math.dist(self.position_m, self.look_at_m) < 1e-6:
                raise ValueError("look_at_m must differ from position_m")
        if self.quaternion_xyzw is not None:
            norm = math.sqrt(sum(v * v for v in self.quaternion_xyzw))
            if not math.isfinite(norm) or abs(norm - 1.0) > 1e-3:
                raise ValueError(f"quaternion_xyzw must have unit norm (got norm {norm:.6g})")
        if self.resolution is not None and min(self.resolution) < 2:
            raise ValueError(f"resolution must be at least 2x2 px, got {list(self.resolution)}")
        if self.focal_px is not None and not min(self.focal_px) > 0.0:
            raise ValueError(f"focal_px must be > 0, got {list(self.focal_px)}")
        if self.range_m is not None and not 0.0 < self.range_m[0] < self.range_m[1]:
            raise ValueError(f"range_m must satisfy 0 < min < max, got {list(self.range_m)}")
        return self


class SensorConfig(_Strict):
    """Simulated depth camera and distance estimation.

    Attributes:
        noise_std_m: Gaussian depth noise σ [m].
        dropout: Fraction of pixels without return (set to 0), in [0, 1).
        rho_m: Half side of each control point's surveillance cube [m].
        self_filter_margin_m: Inflation of the robot geometry removed from the image [m].
        blind_fraction: Valid-pixel fraction under which a frame is "blind" (safe stop).
        max_age_s: Distance estimate older than this → stale → safe stop [s].
        cameras: The depth cameras (``[[sensor.cameras]]``); empty = the scene's one camera as
            the MJCF gives it (the paper's single Kinect). Two or more: per-camera distances
            fused by ``compare.sensing.fusion`` (docs/sensing.md).
        fusion_step_m: Sampling step along hidden half-lines when fusing several cameras [m].
        fusion_tolerance_m: A point counts as seen free by a camera only if it is this much in
            front of its pixel's return, the arm's and the table's included (plus the noise
            allowance) [m].
        min_support: Each control point's distance is the ``min_support``-th smallest pixel
            distance in its cube: 1 = the minimum (the paper's/Flacco's estimate); 2–5 ignore
            that many − 1 isolated stray ("flying") pixels at depth edges, at the price of
            reporting the second-nearest point of a real obstacle. One camera only.
    """

    noise_std_m: float = Field(0.0, ge=0.0, le=0.5)
    dropout: float = Field(0.0, ge=0.0, lt=1.0)
    rho_m: float = Field(0.5, gt=0.0, le=2.0)
    self_filter_margin_m: float = Field(0.03, ge=0.0, le=0.3)
    blind_fraction: float = Field(0.3, ge=0.0, le=1.0)
    max_age_s: float = Field(0.2, gt=0.0)
    cameras: list[CameraConfig] = Field(default_factory=list)
    fusion_step_m: float = Field(0.01, gt=0.0, le=0.1)
    fusion_tolerance_m: float = Field(0.002, ge=0.0, le=0.1)
    min_support: int = Field(1, ge=1, le=5)

    @field_validator("cameras")
    @classmethod
    def _unique_cameras(cls, cameras: list[CameraConfig]) -> list[CameraConfig]:
        names = [c.name for c in cameras]
        if len(set(names)) != len(names):
            raise ValueError(f"camera names must be unique, got {names}")
        return cameras

    @model_validator(mode="after")
    def _support_with_one_camera(self) -> SensorConfig:
        if self.min_support > 1 and len(self.cameras) > 1:
            raise ValueError(
                f"min_support = {self.min_support} needs one camera (got {len(self.cameras)}); "
                "with several cameras the fusion rejects lone pixels itself (docs/sensing.md)"
            )
        return self


class RandomConfig(_Strict):
    """Ranges of the ``random`` scenario family (all drawn from ``scenario.seed``).

    The defaults are the *hard* family of the reliability campaigns (README "Reliability
    campaigns"): a person walking up at up to 1.6 m/s and moving a hand at up to 2.0 m/s (the
    human speeds of ISO 13855 / ISO/TS 15066), from any side, reaching for any control point or
    pushing the end effector toward a wall; start poses near the joint limits; waypoints near the
    walls. ``configs/random.toml`` spells every range out.

    Attributes:
        waypoints: Number of waypoints drawn inside ``workspace_lower``/``upper``.
        workspace_lower: Box for waypoints [m].
        workspace_upper: Box for waypoints [m].
        start_perturbation_rad: Uniform perturbation of the home pose [rad].
        person_speed_mps: Range of the person's walking speed [m/s].
        person_visits: Number of approaches to the arm.
        noise_std_m: Range of depth noise σ [m].
        dropout: Range of pixel dropout fraction.
        hand_speed_mps: Range of the hand's speed while reaching and withdrawing [m/s].
        near_radius_m: Range of the torso's closest approach to the base axis [m].
        reach_targets: What a visit's hand goes for, drawn uniformly: ``waypoint`` (near an EE
            waypoint), a control point frame (that point at the start pose; ``control_points`` =
            every control point of the hierarchy's obstacle tasks, in order), ``push_ee``
            (through the EE position toward the wall on the far side).
        push_depth_m: Range of how far the hand goes past its target, away from the person [m].
        start_near_limit_probability: Per limited joint of a joint-limit task, probability that
            the start value is put just inside a safety threshold.
        start_limit_offset_rad: Range of the distance inside that threshold [rad].
        waypoint_near_wall_probability: Per waypoint, probability that one coordinate is moved
            next to a wall of the EE's ``wall_box``.
        waypoint_wall_offset_m: Range of that coordinate's signed distance past the wall [m]
            (negative = inside the allowed box; up to the waypoint tolerance outside, so the
            waypoint is still reached with the EE held at the wall).
        start_pose_attempts: Draws of the start pose before falling back to the plain perturbed
            home pose (a start pose must have the EE inside the walls and every set task inside
            its safety thresholds).
    """

    waypoints: int = Field(3, ge=1, le=20)
    workspace_lower: Vec3 = (-0.45, -0.45, 0.25)
    workspace_upper: Vec3 = (0.45, 0.45, 0.85)
    start_perturbation_rad: float = Field(0.3, ge=0.0, le=math.pi)
    person_speed_mps: tuple[float, float] = (0.5, 1.6)
    person_visits: int = Field(2, ge=0, le=20)
    noise_std_m: tuple[float, float] = (0.0, 0.01)
    dropout: tuple[float, float] = (0.0, 0.05)
    hand_speed_mps: tuple[float, float] = (0.5, 2.0)
    near_radius_m: tuple[float, float] = (0.7, 0.95)
    reach_targets: list[str] = Field(default_factory=lambda: ["waypoint", "control_points", "push_ee"], min_length=1)
    push_depth_m: tuple[float, float] = (0.05, 0.25)
    start_near_limit_probability: float = Field(0.3, ge=0.0, le=1.0)
    start_limit_offset_rad: tuple[float, float] = (0.005, 0.08)
    waypoint_near_wall_probability: float = Field(0.4, ge=0.0, le=1.0)
    waypoint_wall_offset_m: tuple[float, float] = (-0.04, 0.01)
    start_pose_attempts: int = Field(200, ge=1, le=10000)

    @field_validator(
        "person_speed_mps",
        "noise_std_m",
        "dropout",
        "hand_speed_mps",
        "near_radius_m",
        "push_depth_m",
        "start_limit_offset_rad",
        "waypoint_wall_offset_m",
    )
    @classmethod
    def _ordered_range(cls, rng: tuple[float, float]) -> tuple[float, float]:
        if not (math.isfinite(rng[0]) and math.isfinite(rng[1])) or rng[0] > rng[1]:
            raise ValueError(f"range must be [low, high] with low <= high, got {list(rng)}")
        return rng

    @field_validator("person_speed_mps", "hand_speed_mps")
    @classmethod
    def _positive_speed(cls, rng: tuple[float, float]) -> tuple[float, float]:
        if rng[0] <= 0.0:
            raise ValueError(f"speeds must be > 0 m/s, got {list(rng)}")
        return rng


FaultKind = Literal[
    "depth_nan",
    "depth_zero",
    "depth_dropout",
    "depth_frozen",
    "depth_delay",
    "joint_noise",
    "solver_fail",
    "solver_timeout",
]
"""Kinds of injected faults (``compare.loop.faults`` documents each one)."""


class FaultSpec(_Strict):
    """One injected fault, active on ``[start_s, end_s)`` (both scaled by ``scenario.time_scale``).

    Attributes:
        kind: See :data:`FaultKind` and ``compare.loop.faults``.
        start_s: Start [s].
        end_s: End [s] (exclusive); ``inf`` = until the end of the run.
        fraction: ``depth_nan`` / ``depth_zero`` / ``depth_dropout``: fraction of the pixels hit
            (1 = the whole frame).
        delay_s: ``depth_delay``: age of the frames delivered [s]; ``solver_timeout``: time the
            solve is made to take beyond its own [s].
        std_rad: ``joint_noise``: σ of the Gaussian noise on the joint positions [rad].
        std_rad_s: ``joint_noise``: σ of the noise on the joint velocities [rad/s].
        every_n: ``solver_fail`` / ``solver_timeout``: hit every n-th control step of the window.
        deadline_s: ``solver_timeout``: the solve deadline [s]; default the control period.
        sleep: ``solver_timeout``: really sleep ``delay_s`` (wall time) instead of adding it to the
            measured solve time only (results are identical; sweeps keep ``false``).
        camera: Depth faults: index in ``[[sensor.cameras]]`` of the one camera hit; unset = every
            camera.
    """

    kind: FaultKind
    start_s: float = Field(0.0, ge=0.0)
    end_s: float = math.inf
    fraction: float = Field(1.0, gt=0.0, le=1.0)
    delay_s: float = Field(0.1, ge=0.0, le=10.0)
    std_rad: float = Field(0.002, ge=0.0, le=0.5)
    std_rad_s: float = Field(0.0, ge=0.0, le=5.0)
    every_n: int = Field(1, ge=1)
    deadline_s: float | None = Field(None, gt=0.0)
    sleep: bool = False
    camera: int | None = Field(None, ge=0)

    @model_validator(mode="after")
    def _window(self) -> FaultSpec:
        if not self.end_s > self.start_s:
            raise ValueError(f"end_s ({self.end_s:g}) must be > start_s ({self.start_s:g})")
        return self


class FaultsConfig(_Strict):
    """Faults injected identically into every method's run (``[faults]``, ``compare.loop.faults``).

    Attributes:
        inject: The faults (``[[faults.inject]]`` tables); empty = a fault-free run.
        seed_offset: Added to ``scenario.seed`` for the faults' random draws (pixel masks, noise).
    """

    inject: list[FaultSpec] = Field(default_factory=list)
    seed_offset: int = Field(0, ge=0)


class Iso15066Config(_Strict):
    r"""Speed-and-separation margin of ISO/TS 15066:2016 clause 5.5.4 (``compare.analysis.iso15066``).

    .. math:: S_p = S_h + S_r + S_s + C + Z_d + Z_r,\quad S_h = v_h (T_r + T_s),\quad S_r = v_r T_r

    Defaults (ISO/TS 15066 leaves every value to the application; ours are for the simulated
    Jaco² with a 30 Hz depth camera and a 100 Hz loop):

    Attributes:
        enabled: Compute the margin and write it to ``summary.json`` and the plots.
        reaction_time_s: T_r [s]: one depth period (33 ms) + frame processing + one control
            period (10 ms) + driver latency, rounded up to 0.1 s.
        stopping_time_s: T_s [s]: 0.2 s, the time to brake from the joint speed limits
            (0.63–0.84 rad/s) at the velocity servos' deceleration.
        stopping_distance_m: S_s [m]; ``None`` = :math:`v_r T_s / 2` (constant deceleration).
        intrusion_distance_m: C [m]: 0, the depth camera sees hands and arms themselves (no
            reach-over a detection plane as with ISO 13855 light curtains: there C = 0.85 m).
        sensor_uncertainty_m: Z_d [m]: 0.02, the person's position uncertainty (Kinect v2 depth
            noise at 1–2 m plus the self-filter margin's order).
        robot_uncertainty_m: Z_r [m]: 0.01, control point position uncertainty (model, encoders,
            servo tracking lag).
        human_speed: ``estimated`` (from the motion of the measured closest points, filtered) or
            ``constant`` (:attr:`human_speed_mps` always, ISO 13855's 1.6 m/s walking speed).
        human_speed_mps: v_h in ``constant`` mode [m/s].
        human_speed_filter_s: Time constant of the first-order filter of the estimate [s].
        human_speed_max_mps: The raw estimate is clipped to this [m/s] (a jump of the closest
            point from one body part to another is not a speed).
    """

    enabled: bool = True
    reaction_time_s: float = Field(0.1, ge=0.0, le=5.0)
    stopping_time_s: float = Field(0.2, ge=0.0, le=5.0)
    stopping_distance_m: float | None = Field(None, ge=0.0, le=5.0)
    intrusion_distance_m: float = Field(0.0, ge=0.0, le=2.0)
    sensor_uncertainty_m: float = Field(0.02, ge=0.0, le=1.0)
    robot_uncertainty_m: float = Field(0.01, ge=0.0, le=1.0)
    human_speed: Literal["estimated", "constant"] = "estimated"
    human_speed_mps: float = Field(1.6, ge=0.0, le=10.0)
    human_speed_filter_s: float = Field(0.1, ge=0.0, le=5.0)
    human_speed_max_mps: float = Field(3.0, gt=0.0, le=20.0)


class SolverLimitConfig(_Strict):
    """Per-call time limit of every method's solve (``[solver_limit]``, ``compare.loop.deadline``).

    Enforced on hardware, and in simulation only with ``[loop] realtime = true``: a solve that
    takes longer than the limit is treated as not having arrived: the step uses the loop's
    fallback, is FAILED and counts as a deadline miss (per-step ``deadline_miss``,
    ``deadline_misses`` in summary.json). QP backends with a time limit of their own (OSQP,
    Clarabel, DAQP) also get the remaining budget on every call, on the wall clock.

    Attributes:
        enabled: Enforce the limit (off: no limit; a miss is then a solve longer than the period).
        time_limit_s: The limit [s]; default ``period_fraction`` × the control period.
        period_fraction: Share of the control period given to the solve when ``time_limit_s`` is
            unset (the rest is for sensing, kinematics and I/O).
        simulation_clock: What the limit is measured on in simulation: ``cpu`` (the solver
            thread's CPU time: the verdict does not depend on how loaded the machine is; backend
            time limits are then not set, as they count wall time) or ``wall`` (elapsed time, as on
            hardware). Hardware always uses the wall clock, in a watchdog thread, so the loop
            never waits for a late answer.
        exclude_steal: On the ``cpu`` clock, take the hypervisor's steal time (counted per
            virtual CPU in ``/proc/stat``) out of a solve that looks late: a solve within the limit
            without it keeps its answer and counts in ``deadline_steal_excused``, not as a miss
            (``compare.loop.steal_clock``; no effect where the counter cannot be read).
    """

    enabled: bool = True
    time_limit_s: float | None = Field(None, gt=0.0, le=10.0)
    period_fraction: float = Field(0.5, gt=0.0, le=1.0)
    simulation_clock: Literal["cpu", "wall"] = "cpu"
    exclude_steal: bool = True

    def limit_s(self, dt: float) -> float | None:
        """The limit [s] for control period ``dt`` [s], or None when disabled."""
        if not self.enabled:
            return None
        return float(self.time_limit_s) if self.time_limit_s is not None else self.period_fraction * float(dt)


_NAME = re.compile(r"^(oracle|preview)-(\d+(?:\.\d+)?)s$")


@dataclass(frozen=True)
class WitnessSpec:
    """A witness by name: ``oracle-<T>s`` or ``preview-<τ>s``.

    Attributes:
        policy: ``oracle`` or ``preview``.
        look_ahead_s: The oracle's horizon T or the preview τ [s].
    """

    policy: str
    look_ahead_s: float

    @classmethod
    def parse(cls, name: str) -> WitnessSpec:
        """The spec of ``name``.

        Raises:
            ValueError: ``name`` is not ``oracle-<T>s`` (T ≥ 0.5) or ``preview-<τ>s`` (τ ≤ 5).
        """
        match = _NAME.match(name)
        if match is None:
            raise ValueError(
                f"witness '{name}' is not 'oracle-<T>s' or 'preview-<tau>s' (e.g. oracle-1.5s, preview-0.6s)"
            )
        spec = cls(match.group(1), float(match.group(2)))
        if spec.policy == "oracle" and not 0.5 <= spec.look_ahead_s <= 5.0:
            raise ValueError(f"witness '{name}': the oracle's horizon must be in [0.5, 5] s")
        if spec.policy == "preview" and spec.look_ahead_s > 5.0:
            raise ValueError(f"witness '{name}': the preview must be at most 5 s")
        return spec

    @property
    def name(self) -> str:
        """The witness's name (``oracle-1.5s``)."""
        return f"{self.policy}-{self.look_ahead_s:g}s"


DEFAULT_WITNESSES = (
    "preview-1s",
    "oracle-1.5s",
    "oracle-2s",
    "preview-0.6s",
    "oracle-1s",
    "oracle-3s",
    "preview-0.3s",
    "preview-0s",
)
"""The verdict's witnesses, in the order tried: the most often successful first (docs/separating.md)."""


class LoopConfig(_Strict):
    """How the simulated loop treats time (``[loop]``).

    Attributes:
        realtime: Enforce ``[solver_limit]`` in simulation as on hardware: a solve that has not
            answered within the limit is replaced by the fallback (FAILED step), and QP backends
            get what is left of the budget. The trajectory then depends on the machine's speed and
            load. Off (the default): every solve's answer is applied, so a run is a function of
            (config, seed) alone; a solve longer than the control period is reported as a deadline
            miss and changes nothing.
    """

    realtime: bool = False


class PredictionConfig(_Strict):
    r"""Anticipating the person inside the shared obstacle tasks (``[prediction]``, :mod:`compare.sensing.prediction`).

    Every method's obstacle tasks receive the same prediction through the one control reference
    (docs/separating.md, "Anticipating the person").

    Attributes:
        mode: ``off`` (the paper's tasks), ``estimated`` (the motion of each closest obstacle
            point, Kalman-filtered from the sensing stream alone) or ``truth`` (the person's true
            future: the bound of what prediction can do).
        feedforward: (a) the predicted closing speed f as rate feed-forward,
            :math:`K(\sigma_s - \sigma) + f`.
        horizon_s: (b) τ [s]: the task's point is the predicted obstacle point nearest to the
            control point over [t, t + τ]; 0 = off.
        growth: (c) every obstacle threshold grows by :math:`f\,(T_r + T_s)` (ISO/TS 15066's human
            term with the ``[iso15066]`` reaction and stopping times).
        sample_s: Step of the true future over the horizon (``truth``) [s].
        acceleration_mps2: The estimate's white-noise acceleration a [m/s²].
        measurement_noise_m: The estimate's noise of a measured closest point [m].
        occluded_noise_m: Its noise of a point assumed from occluded space [m] (followed itself:
            ``hidden_surface = false``, or nothing of the surface hiding it measured).
        hidden_surface: A point assumed from hidden space is followed at the measured surface
            hiding it, and the person may close in behind that surface as fast as it closes in
            (``compare.sensing.prediction``); false: the assumed point itself is followed.

    The sensing range ``[sensor] rho_m`` bounds what is seen (and so what can be predicted): a
    larger ρ sees the person earlier and costs more depth pixels per frame.
    """

    mode: Literal["off", "estimated", "truth"] = "off"
    feedforward: bool = True
    horizon_s: float = Field(0.25, ge=0.0, le=3.0)
    growth: bool = True
    sample_s: float = Field(0.05, gt=0.0, le=0.5)
    acceleration_mps2: float = Field(8.0, gt=0.0, le=100.0)
    measurement_noise_m: float = Field(0.01, gt=0.0, le=0.5)
    occluded_noise_m: float = Field(0.05, gt=0.0, le=1.0)
    hidden_surface: bool = True

    def settings(self, iso: Iso15066Config, range_m: float) -> PredictionSettings | None:
        """The predictor's settings (None when ``mode = "off"``); ``range_m`` is the sensing range ρ [m]."""
        if self.mode == "off":
            return None
        return PredictionSettings(
            mode=self.mode,
            feedforward=self.feedforward,
            horizon_s=self.horizon_s,
            growth_time_s=iso.reaction_time_s + iso.stopping_time_s if self.growth else 0.0,
            sample_s=self.sample_s,
            range_m=range_m,
            hidden_surface=self.hidden_surface,
            motion_filter=MotionFilterSettings(
                acceleration_mps2=self.acceleration_mps2,
                measurement_m=self.measurement_noise_m,
                occluded_m=self.occluded_noise_m,
            ),
        )


class OracleConfig(_Strict):
    r"""The run's verdict (``[oracle]``, :mod:`compare.campaign.verdict`): avoidable, unavoidable or undecided.

    Witnesses that know the scripted person's future drive the same plant under the same limits:
    one that keeps every safety threshold labels the run ``avoidable``; when none does, a
    reachability certificate may prove it ``unavoidable``; otherwise it is ``undecided``
    (docs/design.md §5, §7). Every method's obstacle violations are counted under the run's label.

    Attributes:
        enabled: Compute the verdict for each run (``summary.json`` gets ``oracle`` and every
            method ``obstacle_violations``).
        witnesses: The witnesses, in the order they are tried: ``oracle-<T>s`` (the clairvoyant
            receding-horizon optimiser with horizon T ≥ 0.5 s, :mod:`compare.campaign.oracle`) and
            ``preview-<τ>s`` (the greedy preview policy looking τ ahead, :mod:`compare.campaign.preview`).
        witness_rule: ``first``: stop at the first witness that holds; ``all``: run every witness
            (the best is kept either way).
        certificate_voxel_m: Cube side δ of the reachability certificate [m] (finer: stronger
            and slower).
        knot_s: The oracle's plan resolution h [s]: piecewise-constant joint velocities over
            N = ⌈T/h⌉ knots.
        replan_period_s: Time between two optimisations of the oracle [s] (the plan is followed in
            between).
        sqp_iterations: Linearise-and-solve iterations per optimisation (sequential QP).
        trust_region_rad_s: Largest change of a knot velocity per iteration [rad/s].
        margin_cap_m: Every witness stops pushing once every control point is this far beyond its
            safety threshold over its look-ahead [m]; it then holds still.
        secondary_weight: μ: weight of the oracle's mean per-knot minimum margin next to the
            overall minimum (the primary objective).
        solver: qpsolvers backend of the witnesses' QPs (one of the project's HQP backends).
        avoidable_only: Random family only: redraw a scenario until it is labelled ``avoidable``
            (the avoidable family; ``configs/random_avoidable.toml``).
        max_draws: Draws tried per run before giving up (the last draw is then kept, marked).
        keep_steps: Also cache the witnesses' per-step tables (large; for investigating a seed).
    """

    enabled: bool = False
    witnesses: list[str] = Field(
        default_factory=lambda: list(DEFAULT_WITNESSES),
        min_length=1,
    )
    witness_rule: Literal["first", "all"] = "first"
    certificate_voxel_m: float = Field(0.04, ge=0.01, le=0.2)
    knot_s: float = Field(0.1, gt=0.0, le=0.5)
    replan_period_s: float = Field(0.05, gt=0.0, le=0.5)
    sqp_iterations: int = Field(2, ge=1, le=20)
    trust_region_rad_s: float = Field(0.4, gt=0.0, le=10.0)
    margin_cap_m: float = Field(0.25, gt=0.0, le=5.0)
    secondary_weight: float = Field(0.1, ge=0.0, le=10.0)
    solver: str = "daqp"
    avoidable_only: bool = False
    max_draws: int = Field(50, ge=1, le=10000)
    keep_steps: bool = False

    @model_validator(mode="after")
    def _consistent(self) -> OracleConfig:
        if len(set(self.witnesses)) != len(self.witnesses):
            raise ValueError(f"witnesses are listed twice: {self.witnesses}")
        for name in self.witnesses:
            spec = WitnessSpec.parse(name)
            if spec.policy == "oracle" and self.knot_s > spec.look_ahead_s:
                raise ValueError(f"knot_s ({self.knot_s:g}) must be <= the horizon of witness '{name}'")
        if self.avoidable_only and not self.enabled:
            raise ValueError("avoidable_only needs enabled = true (the draws are filtered by the verdict)")
        if self.solver not in available_qp_solvers():
            raise ValueError(f"unknown QP solver '{self.solver}'; available: {', '.join(available_qp_solvers())}")
        return self


class LevelConfig(_Strict):
    """One priority level, highest first; task tables are checked by :meth:`tpik.Hierarchy.from_description`.

    Attributes:
        name: Level name (e.g. ``joint_limits``, ``operational``).
        tasks: Task tables ``{type = "...", ...}`` of the level; each type's keys are listed below.
    """

    name: str
    tasks: list[dict[str, Any]] = Field(min_length=1)


class MethodsConfig(_Strict):
    """Which methods run, and their settings by method name.

    Attributes:
        names: Method names (``tpik-compare methods`` lists them: ``tpik``, ``hqp-<qp solver>``, ``mink``, ...).
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


USB_STATE_RATE_HZ = 45.0
"""Joint-state rate the kinova-ros driver reaches over USB with ``feedback_publish_rate`` ≤ 0.02 s:
its status timer makes nine blocking API calls of ~2 ms each (kinova-ros issues #281: "barely
40 Hz", #372: "40–60 Hz"; ``compare.hardware.driver_model``). Over Ethernet it is 1 / feedback_publish_rate."""


class HardwareConfig(_Strict):
    """The real Jaco² and depth camera through ROS 1 (``tpik-compare hw``, docs/hardware.md).

    Topics default to the kinova-ros driver of a j2s7s300 and a Kinect v2 bridge. The driver's
    launch settings are stated here (``connection_type``, ``feedback_publish_rate_s``): they
    set the joint-state rate to expect, and from it the start check and the watchdog.

    Attributes:
        node_name: ROS node name of the controller.
        joint_state_topic: ``sensor_msgs/JointState`` from the driver (positions in rad).
        velocity_topic: ``kinova_msgs/JointVelocity`` to the driver (deg/s, 100 Hz).
        stop_service: ``kinova_msgs/Stop`` of the driver (stops the arm, erases its trajectory FIFO).
        start_service: ``kinova_msgs/Start`` of the driver (re-enables commands after a stop).
        service_timeout_s: Wait for a service to exist / answer [s].
        joint_names: Names of the arm joints in the joint state, in model order (one per joint of
            ``scenario.robot``); empty = the robot description's joint names (the kinova-ros
            driver's own for the Jaco²). :func:`parse_config` fills them in.
        depth_topic: ``sensor_msgs/Image`` depth (16UC1 in mm or 32FC1 in m).
        camera_info_topic: ``sensor_msgs/CameraInfo`` of the depth image.
        connection_type: ``usb`` or ``ethernet``: the driver's ``connection_type``
            (``kinova_bringup/launch/config/robot_parameters.yaml``, default USB).
        feedback_publish_rate_s: The driver's launch argument ``feedback_publish_rate``
            (``status_interval_seconds``) [s].
        state_rate_hz: Joint-state rate to expect [Hz]; default: 1 / ``feedback_publish_rate_s``,
            at most :data:`USB_STATE_RATE_HZ` over USB.
        min_state_rate_fraction: Start refuses if the measured median state rate is below this
            fraction of the expected rate.
        state_timeout_periods: Watchdog: no joint state for this many expected periods → zero
            velocity and ``in/stop`` (5: 111 ms over USB, 50 ms over Ethernet at 0.01 s).
        depth_timeout_s: Watchdog: no depth frame for this long → zero velocity [s].
        loop_timeout_s: Watchdog: no new command from the control loop for this long → zero
            velocity [s] (the command stream re-sends the held command until then).
        max_velocity_scale: Fraction of the model's joint velocity limits allowed on hardware.
        max_acceleration_rad_s2: Clamp on the change of the commanded velocity [rad/s²].
        camera_translation_m: Optical-frame origin in the arm base frame [m] (calibrated).
        camera_quaternion_xyzw: Optical-frame orientation in the base frame, (x, y, z, w) as
            ``tf``/``static_transform_publisher`` print it. Both or neither; missing → no start.
        calibration_max_residual_m: ``hw`` refuses to move when the alignment residual (75th
            percentile of the depth error over the arm's pixels: the arm model rendered from the
            configured camera pose vs the live depth,
            ``tpik-compare hw-check``) exceeds this [m]; 0 = no check.
        depth_min_range_m: Closest valid depth [m].
        depth_max_range_m: Farthest valid depth [m].
        use_depth: Use the depth camera (required when the hierarchy has obstacle tasks).
        background_file: Background depth image of the static scene (``.npz`` written by
            ``tpik-compare hw --capture-background``); when set, no capture at start.
        background_capture_s: Otherwise, time spent at start capturing the static scene (table,
            floor) from live frames, removed from every later frame; nobody may be in view [s].
            0 = no background removal.
        startup_timeout_s: Time to wait for the first joint state, camera info and depth [s].
        other_command_topics: The driver's other inputs that move the arm (Cartesian velocity,
            torque and force, the goals of its joint, pose and finger actions): nobody may publish
            on them while the bridge runs; with ``velocity_topic`` they are watched for foreign
            publishers (docs/hardware.md, "Network").
        allow_network_master: Run even when ``ROS_MASTER_URI`` names another host, or the master
            or this node listens beyond loopback (``--allow-network-master``). ROS 1 cannot
            authenticate: only on a dedicated network behind a firewall (docs/hardware.md, "Network").
    """

    node_name: str = "tpik_compare"
    joint_state_topic: str = "/j2s7s300_driver/out/joint_state"
    velocity_topic: str = "/j2s7s300_driver/in/joint_velocity"
    stop_service: str = "/j2s7s300_driver/in/stop"
    start_service: str = "/j2s7s300_driver/in/start"
    service_timeout_s: float = Field(2.0, gt=0.0, le=30.0)
    joint_names: tuple[str, ...] = ()
    depth_topic: str = "/kinect2/sd/image_depth_rect"
    camera_info_topic: str = "/kinect2/sd/camera_info"
    connection_type: Literal["usb", "ethernet"] = "usb"
    feedback_publish_rate_s: float = Field(0.01, gt=0.0, le=1.0)
    state_rate_hz: float | None = Field(None, gt=0.0, le=1000.0)
    min_state_rate_fraction: float = Field(0.7, ge=0.0, le=1.0)
    state_timeout_periods: float = Field(5.0, ge=1.0, le=100.0)
    depth_timeout_s: float = Field(0.2, gt=0.0, le=5.0)
    loop_timeout_s: float = Field(0.1, ge=0.03, le=1.0)
    max_velocity_scale: float = Field(1.0, gt=0.0, le=1.0)
    max_acceleration_rad_s2: float = Field(4.0, gt=0.0, le=100.0)
    camera_translation_m: Vec3 | None = None
    camera_quaternion_xyzw: Vec4 | None = None
    calibration_max_residual_m: float = Field(0.02, ge=0.0, le=1.0)
    depth_min_range_m: float = Field(0.5, ge=0.0)
    depth_max_range_m: float = Field(4.5, gt=0.0)
    use_depth: bool = True
    background_file: str | None = None
    background_capture_s: float = Field(1.0, ge=0.0, le=30.0)
    startup_timeout_s: float = Field(5.0, gt=0.0, le=120.0)
    other_command_topics: tuple[str, ...] = (
        "/j2s7s300_driver/in/cartesian_velocity",
        "/j2s7s300_driver/in/cartesian_velocity_with_fingers",
        "/j2s7s300_driver/in/cartesian_velocity_with_finger_velocity",
        "/j2s7s300_driver/in/joint_torque",
        "/j2s7s300_driver/in/cartesian_force",
        "/j2s7s300_driver/joints_action/joint_angles/goal",
        "/j2s7s300_driver/pose_action/tool_pose/goal",
        "/j2s7s300_driver/fingers_action/finger_positions/goal",
    )
    allow_network_master: bool = False

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
    def expected_state_rate_hz(self) -> float:
        """Joint-state rate to expect [Hz] (``state_rate_hz``, or from the connection and feedback rate)."""
        if self.state_rate_hz is not None:
            return self.state_rate_hz
        rate = 1.0 / self.feedback_publish_rate_s
        return min(rate, USB_STATE_RATE_HZ) if self.connection_type == "usb" else rate

    @property
    def state_timeout_s(self) -> float:
        """Joint-state watchdog timeout [s]: ``state_timeout_periods`` expected state periods."""
        return self.state_timeout_periods / self.expected_state_rate_hz

    @property
    def has_camera_transform(self) -> bool:
        """Whether the calibrated camera pose is given."""
        return self.camera_translation_m is not None and self.camera_quaternion_xyzw is not None


class ExtensionsConfig(_Strict):
    """Python modules imported before the hierarchy is built, e.g. new task types or metrics (docs/extending.md).

    Attributes:
        modules: Module names importable from ``sys.path`` (``my_package.my_tasks``) or ``.py``
            files; a relative file path is relative to the config file (to the working directory
            when the config does not come from a file). Each module registers its task types with
            :func:`tpik.register_task` and its metrics with
            :func:`compare.analysis.metrics.register_metric` when imported; every process that
            builds the hierarchy (sweep workers included) and a sweep's own process import them.
    """

    modules: list[str] = Field(default_factory=list)


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
    faults: FaultsConfig = Field(default_factory=FaultsConfig)
    iso15066: Iso15066Config = Field(default_factory=Iso15066Config)
    extensions: ExtensionsConfig = Field(default_factory=ExtensionsConfig)
    solver_limit: SolverLimitConfig = Field(default_factory=SolverLimitConfig)
    loop: LoopConfig = Field(default_factory=LoopConfig)
    oracle: OracleConfig = Field(default_factory=OracleConfig)
    prediction: PredictionConfig = Field(default_factory=PredictionConfig)

    def hierarchy_description(self) -> list[dict[str, Any]]:
        """The levels as the plain description :meth:`Hierarchy.from_description` takes."""
        return [{"name": lv.name, "tasks": [dict(t) for t in lv.tasks]} for lv in self.levels]

    def build_hierarchy(self, robot: robots.Robot) -> Hierarchy:
        """A fresh hierarchy (each method gets its own: tasks carry targets and obstacles).

        The ``[extensions]`` modules are imported first (once per process).

        Raises:
            ConfigError: An extension module cannot be imported.
            tpik.TaskDefinitionError: A bad task description (naming ``levels[i].tasks[k]`` and the key).
        """
        import_extensions(self.extensions.modules)
        return Hierarchy.from_description(self.hierarchy_description(), robot)

    def load_robot(self) -> robots.Robot:
        """The arm of ``[scenario] robot`` (parsed once per process)."""
        return robots.load(self.scenario.robot)


_EXTENSIONS: dict[str, ModuleType] = {}
"""Extension modules imported in this process, by their ``[extensions]`` entry."""


def import_extensions(modules: list[str]) -> None:
    """Import the ``[extensions] modules`` not imported yet in this process.

    Raises:
        ConfigError: naming ``extensions.modules[i]``, when a module cannot be found or fails while
            being imported (a bad registration included).
    """
    for i, entry in enumerate(modules):
        if entry in _EXTENSIONS:
            continue
        where = f"extensions.modules[{i}]"
        try:
            module = _import_file(Path(entry), where) if entry.endswith(".py") else importlib.import_module(entry)
        except ConfigError:
            raise
        except Exception as exc:  # noqa: BLE001 - whatever a user module raises on import is a config error
            raise ConfigError(f"{where}: cannot import {entry!r}: {type(exc).__name__}: {exc}") from exc
        _EXTENSIONS[entry] = module


def _import_file(path: Path, where: str) -> ModuleType:
    """Import a ``.py`` file as a module named after its absolute path (the same file is one module)."""
    path = path.resolve()
    if not path.is_file():
        raise ConfigError(f"{where}: no Python file {path}")
    name = f"tpik_extension_{path.stem}_{hashlib.sha1(str(path).encode()).hexdigest()[:8]}"
    spec = importlib.util.spec_from_file_location(name, path)
    if spec is None or spec.loader is None:
        raise ConfigError(f"{where}: cannot load {path} as a Python module")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    try:
        spec.loader.exec_module(module)
    except BaseException:
        del sys.modules[name]
        raise
    return module


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
    if robot is None:
        try:
            robot = config.load_robot()
        except robots.RobotError as exc:
            raise ConfigError(f"scenario.robot: {exc}") from None
    _check_robot_keys(config, robot)
    if not config.hardware.joint_names:
        hardware = config.hardware.model_copy(update={"joint_names": tuple(robot.joint_names)})
        config = config.model_copy(update={"hardware": hardware})
    try:
        hierarchy = config.build_hierarchy(robot)
    except (TpikError, robots.RobotError) as exc:
        message = str(exc)
        raise ConfigError(message if message.startswith("levels") else f"levels: {message}") from None
    if config.oracle.enabled and not any(isinstance(t, ObstacleDistanceTask) for t in hierarchy.set_tasks):
        raise ConfigError("oracle.enabled: the hierarchy has no obstacle_distance task for the oracle to keep")
    _check_methods(config, robot)
    _check_cameras(config, robot)
    return config


def _check_robot_keys(config: Config, robot: robots.Robot) -> None:
    """Keys whose size or names depend on the arm: start pose, hardware joints, reach targets."""
    sc = config.scenario
    if sc.start_q is not None and len(sc.start_q) != robot.nq:
        raise ConfigError(f"scenario.start_q: {len(sc.start_q)} values for the {robot.nq} joints of '{robot.name}'")
    names = config.hardware.joint_names
    if names and len(names) != robot.nq:
        raise ConfigError(f"hardware.joint_names: {len(names)} names for the {robot.nq} joints of '{robot.name}'")
    for i, target in enumerate(config.random.reach_targets):
        if target in ("waypoint", "push_ee", "control_points"):
            continue
        try:
            robot.frame_id(target)
        except robots.UnknownFrame:
            raise ConfigError(
                f"random.reach_targets[{i}]: '{target}' is neither waypoint, push_ee, control_points "
                f"nor a frame of '{robot.name}'"
            ) from None


def _check_cameras(config: Config, robot: robots.Robot) -> None:
    """Every ``[[sensor.cameras]]`` is in the scene or has a pose, and is not slower than the sensing rate."""
    cameras = config.sensor.cameras
    for i, spec in enumerate(config.faults.inject):
        if spec.camera is not None and spec.camera >= max(1, len(cameras)):
            raise ConfigError(f"faults.inject[{i}].camera: no camera {spec.camera} (there are {max(1, len(cameras))})")
    if not cameras:
        return
    in_scene = scene_camera_names(robot.name)
    rate = config.scenario.sensing_rate_hz
    for i, cam in enumerate(cameras):
        if cam.name not in in_scene and cam.position_m is None:
            raise ConfigError(
                f"sensor.cameras[{i}].position_m: camera '{cam.name}' is not in the scene "
                f"({', '.join(in_scene) or 'none'}): give position_m and look_at_m or quaternion_xyzw"
            )
        if cam.rate_hz is not None and cam.rate_hz < rate - 1e-9:
            raise ConfigError(
                f"sensor.cameras[{i}].rate_hz: {cam.rate_hz:g} Hz is slower than scenario.sensing_rate_hz "
                f"= {rate:g} Hz (its frames would be judged stale); lower the sensing rate"
            )


def _check_methods(config: Config, robot: robots.Robot) -> None:
    # Deferred: importing compare.config (as the replay and analysis modules do) loads no method
    # registry; checking the methods does (tests/compare/replay/test_run_data.py).
    from compare.methods import UnknownMethod, make_method

    for i, name in enumerate(config.methods.names):
        try:
            make_method(name, robot, config.methods.settings.get(name))
        except UnknownMethod as exc:
            raise ConfigError(f"methods.names[{i}]: {exc}") from None
        except (TpikError, HqpError) as exc:  # InvalidSettings (backend rejections wrapped), UnknownSolver
            raise ConfigError(f"methods.settings.{name}: {exc}") from None


def _resolve_extension_files(data: dict[str, Any], base: Path) -> None:
    """Make relative ``.py`` paths of ``[extensions] modules`` relative to the config's folder."""
    extensions = data.get("extensions")
    if not isinstance(extensions, dict):
        return
    modules = extensions.get("modules")
    if isinstance(modules, list):
        extensions["modules"] = [
            str((base / m).resolve()) if isinstance(m, str) and m.endswith(".py") and not Path(m).is_absolute() else m
            for m in modules
        ]


def override_value(text: str) -> Any:
    """The value of a command-line override ``KEY=VALUE``: a TOML value, a bare word as a string."""
    try:
        return tomllib.loads(f"v = {text.strip()}")["v"]
    except tomllib.TOMLDecodeError:
        return text.strip()


def load_config(path: str | Path, overrides: dict[str, Any] | None = None) -> tuple[Config, str]:
    """Read and validate a TOML config file; returns the config and its TOML text.

    The text is the file's own when there are no overrides; with overrides it is the effective
    configuration written back as TOML (headed by a comment naming the file and the overrides),
    so the ``config.toml`` copied into a results directory reproduces the run.

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
    _resolve_extension_files(data, p.parent)
    config = parse_config(data)
    if overrides:
        listed = ", ".join(f"{k} = {v!r}" for k, v in overrides.items())
        text = f"# {p.name} with command-line overrides: {listed}\n" + tomli_w.dumps(data)
    return config, text


def dump_config(config: Config) -> str:
    """``config`` as TOML text that :func:`parse_config` (or :func:`load_config`) reads back to an equal config."""
    return tomli_w.dumps(config.model_dump(mode="python", exclude_none=True))

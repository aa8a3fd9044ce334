"""Assemble one simulated run: work-cell model, scripted person, sensing, and the RobotIO.

Kept apart from the loop so the same loop runs on hardware (``compare.hardware``).
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

import robots
from compare.config import Config
from compare.loop.closed_loop import ObstacleSource, control_points
from compare.loop.robot_io import RobotIO
from compare.loop.sim_io import SimRobotIO
from compare.sensing.fusion import FusionSettings
from compare.sensing.geometric_distance import GeometricDistance
from compare.sensing.ground_truth import GroundTruth
from compare.sensing.person import Person
from compare.sensing.person_track import PersonTrack
from compare.sensing.pipeline import (
    DepthPipeline,
    DepthRig,
    DepthSensingSettings,
    GeometricObstacleSource,
    truth_function,
)
from compare.sensing.prediction import EstimatedPrediction, Predictor, TruePrediction
from compare.sensing.rig import load_rig_workcell
from compare.sensing.scene import load_workcell


@dataclass
class Simulation:
    """Everything :func:`compare.loop.closed_loop.run_loop` needs for one simulated run.

    Attributes:
        io: The MuJoCo RobotIO (owns ``model``/``data``).
        obstacles: Depth or geometric obstacle source.
        truth: Ground-truth distance per control point [m], from the person's capsules (called a
            step, or recording the steps for the end: :class:`~compare.sensing.ground_truth.GroundTruth`).
        person: The scripted person.
        pipeline: The depth pipeline (None in geometric mode): one camera's
            :class:`DepthPipeline`, or a :class:`DepthRig` with ``[[sensor.cameras]]`` of two or more.
        control_points: The control point frames sensed (``compare.loop.closed_loop.control_points``).
    """

    io: SimRobotIO
    obstacles: ObstacleSource
    truth: GroundTruth
    person: Person
    pipeline: DepthPipeline | DepthRig | None = None
    control_points: tuple[str, ...] = ()

    def depth_source(self, io: RobotIO) -> ObstacleSource:
        """The depth obstacle source reading its frames from ``io`` (e.g. a fault-injecting wrapper)."""
        if self.pipeline is None:
            raise ValueError("geometric sensing has no depth source")
        return depth_source(self.pipeline, io, self.control_points)

    def close(self) -> None:
        """Free rendering resources."""
        if self.pipeline is not None:
            self.pipeline.close()


def build_simulation(config: Config, robot: robots.Robot, q0: np.ndarray) -> Simulation:
    """Build the work cell for ``config`` (already realized) with the arm at ``q0`` [rad]."""
    sc = config.scenario
    cps = control_points(config.build_hierarchy(robot), robot)
    cameras = config.sensor.cameras if sc.sensing == "depth" else []
    model: mujoco.MjModel = load_rig_workcell(robot.name, cameras) if cameras else load_workcell(robot.name)
    person = Person(model, config.person.keyframes, time_scale=sc.time_scale, sample_period_s=sc.dt)
    pipeline: DepthPipeline | DepthRig | None = None
    depth_camera = None
    depth_cameras = None
    depth_periods = None
    if sc.sensing == "depth":
        settings = DepthSensingSettings.for_cameras(config.sensor, seed=sc.seed, robot_root_body=robot.base_body)
        if len(settings) == 1:
            pipeline = DepthPipeline(model, settings[0])
            depth_camera = pipeline.render
        else:
            fusion = FusionSettings(config.sensor.fusion_step_m, config.sensor.fusion_tolerance_m)
            pipeline = DepthRig(model, settings, fusion)
            depth_cameras = [p.render for p in pipeline.pipelines]
            depth_periods = [1.0 / (cam.rate_hz or sc.sensing_rate_hz) for cam in cameras]
    io = SimRobotIO(
        model,
        robot.nq,
        sc.dt,
        q0,
        mode=sc.simulation,
        drive=sc.drive,
        drive_bandwidth_rad_s=sc.drive_bandwidth_rad_s,
        scene_update=person.apply,
        depth_camera=depth_camera,
        depth_period_s=1.0 / ((cameras[0].rate_hz if cameras else None) or sc.sensing_rate_hz),
        depth_cameras=depth_cameras,
        depth_periods_s=depth_periods,
    )
    obstacles: ObstacleSource
    if pipeline is not None:
        obstacles = depth_source(pipeline, io, cps)
    else:
        obstacles = GeometricObstacleSource(GeometricDistance(model, rho_m=config.sensor.rho_m), io.data, cps)
    return Simulation(io, obstacles, truth_function(model, io.data, cps), person, pipeline, cps)


def depth_source(pipeline: DepthPipeline | DepthRig, io: RobotIO, frames: tuple[str, ...]) -> ObstacleSource:
    """The obstacle source of a depth pipeline or rig for the control points ``frames``, reading from ``io``."""
    if isinstance(pipeline, DepthRig):
        return pipeline.source(io.read_depth_frames, frames)
    return pipeline.source(io.read_depth, frames)


def make_predictor(config: Config, sim: Simulation) -> Predictor | None:
    """The ``[prediction]`` of ``config`` for the run ``sim`` (None when ``mode = "off"``).

    ``truth`` looks the person up on a track sampled at the control period over the run and its
    longest horizon; its clock is the simulation's.
    """
    settings = config.prediction.settings(config.iso15066, config.sensor.rho_m)
    if settings is None:
        return None
    if settings.mode == "estimated":
        return EstimatedPrediction(settings, sim.control_points)
    sc = config.scenario
    track = PersonTrack.from_person(sim.person, sc.sim_time_s + settings.horizon_s + 1.0, sc.dt)
    io = sim.io
    return TruePrediction(settings, sim.control_points, track, lambda _t: io.now())

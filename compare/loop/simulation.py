"""Assemble one simulated run: work-cell model, scripted person, sensing, and the RobotIO.

Kept apart from the loop so the same loop runs on hardware (``compare.hardware``).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass

import mujoco
import numpy as np

import robots
from compare.config import Config
from compare.loop.closed_loop import ObstacleSource, control_points
from compare.loop.sim_io import SimRobotIO
from compare.sensing.geometric_distance import GeometricDistance
from compare.sensing.person import Person
from compare.sensing.pipeline import (
    DepthPipeline,
    DepthSensingSettings,
    GeometricObstacleSource,
    truth_function,
)
from compare.sensing.scene import load_workcell


@dataclass
class Simulation:
    """Everything :func:`compare.loop.closed_loop.run_loop` needs for one simulated run.

    Attributes:
        io: The MuJoCo RobotIO (owns ``model``/``data``).
        obstacles: Depth or geometric obstacle source.
        truth: Ground-truth distance per control point [m], from the person's capsules.
        person: The scripted person.
        pipeline: The depth pipeline (None in geometric mode).
        control_points: The control point frames sensed (``compare.loop.closed_loop.control_points``).
    """

    io: SimRobotIO
    obstacles: ObstacleSource
    truth: Callable[[robots.Kinematics], Mapping[str, float]]
    person: Person
    pipeline: DepthPipeline | None = None
    control_points: tuple[str, ...] = ()

    def close(self) -> None:
        """Free rendering resources."""
        if self.pipeline is not None:
            self.pipeline.close()


def build_simulation(config: Config, robot: robots.Robot, q0: np.ndarray) -> Simulation:
    """Build the work cell for ``config`` (already realized) with the arm at ``q0`` [rad]."""
    sc = config.scenario
    model: mujoco.MjModel = load_workcell(robot.name)
    cps = control_points(config.build_hierarchy(robot), robot)
    person = Person(model, config.person.keyframes, time_scale=sc.time_scale)
    pipeline: DepthPipeline | None = None
    depth_camera = None
    if sc.sensing == "depth":
        settings = DepthSensingSettings.from_sensor_config(config.sensor, seed=sc.seed, robot_root_body=robot.base_body)
        pipeline = DepthPipeline(model, settings)
        depth_camera = pipeline.render
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
        depth_period_s=1.0 / sc.sensing_rate_hz,
    )
    obstacles: ObstacleSource
    if pipeline is not None:
        obstacles = pipeline.source(io.read_depth, cps)
    else:
        obstacles = GeometricObstacleSource(GeometricDistance(model, rho_m=config.sensor.rho_m), io.data, cps)
    return Simulation(io, obstacles, truth_function(model, io.data, cps), person, pipeline, cps)

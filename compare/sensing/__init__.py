"""Simulated depth sensing and obstacle distance (paper sec. III; docs/design.md §4).

Scene: the robot's work cell (``robots/workcell/``: arm on its table, Kinect-v2-like depth
camera, capsule person on mocap bodies; :meth:`robots.Robot.workcell_model`). Two sensing modes with one result type
(:class:`DistanceResult` holding an :class:`ObstacleReading` per control point):

* **depth**: :class:`DepthPipeline` renders a :class:`~compare.loop.robot_io.DepthFrame`
  (:class:`DepthCamera`, noise and dropout), removes the static scene
  (:class:`StaticBackground`) and the arm (:class:`SelfFilter`), and computes the
  depth-space distance of each control point (:class:`DepthDistance`, Flacco et al.);
* **geometric**: :class:`GeometricDistance`, exact distance to the person's capsules.

Several cameras (``[[sensor.cameras]]``): :func:`load_rig_workcell` adds them to the scene,
:class:`DepthRig` runs a pipeline per camera and fuses the distances (:class:`DepthFusion`,
``compare.sensing.fusion``); every reading says whether it was measured or assumed from hidden
space (``ObstacleReading.occluded``) and by which camera (``.camera``).

Example (headless: ``MUJOCO_GL=egl``)::

    import mujoco
    import robots
    from compare.sensing import (DepthPipeline, GeometricDistance, Person, PersonKeyframe,
                                 control_point_positions, load_workcell, make_data)

    arm = robots.load(robots.DEFAULT_ROBOT)       # any name of robots.available_robots()
    model = load_workcell(arm.name)
    data = make_data(model)                       # arm at "home"
    person = Person(model, [PersonKeyframe(0.0, (0.0, 1.35), yaw=-1.5708),
                            PersonKeyframe(2.0, (0.05, 0.95), yaw=-1.5708, right_hand=(0, 0.62, 0.75))])
    person.apply(t=1.0, data=data)                # mocap poses at t = 1 s
    mujoco.mj_forward(model, data)
    kin = arm.kinematics(data.qpos[: arm.nq])
    points = control_point_positions(kin, arm.control_points)   # {frame: position [m]}
    depth = DepthPipeline(model)                  # default DepthSensingSettings (rho 0.5 m)
    result = depth.sense(data, points)            # render + filter + distance
    exact = GeometricDistance(model).compute(data, points)
    depth.close()

In the closed loop (``compare.loop.simulation``): ``person.apply`` is the ``scene_update`` of
``compare.loop.sim_io.SimRobotIO``, ``DepthPipeline.render`` its ``depth_camera``,
``DepthPipeline.source(io.read_depth)`` or ``GeometricObstacleSource`` the loop's obstacle
source, and ``truth_function(model, io.data)`` its ground truth.
"""

from __future__ import annotations

from compare.sensing.camera import (
    DepthNoise,
    camera_model_from_mujoco,
    deproject,
    point_cloud,
    project,
    set_camera_look_at,
    valid_fraction,
)
from compare.sensing.depth_distance import DepthDistance
from compare.sensing.exceptions import SensingError, UnknownSceneElement
from compare.sensing.fusion import DepthFusion, FusionSettings
from compare.sensing.geometric_distance import GeometricDistance, closest_on_capsules
from compare.sensing.person import Person, PersonKeyframe, PersonPose
from compare.sensing.pipeline import (
    DepthObstacleSource,
    DepthPipeline,
    DepthRig,
    DepthSensingSettings,
    GeometricObstacleSource,
    RigObstacleSource,
    truth_function,
)
from compare.sensing.renderer import PERSON_GROUP, ROBOT_VISUAL_GROUP, STATIC_GROUP, DepthCamera
from compare.sensing.results import DistanceResult, ObstacleReading
from compare.sensing.rig import load_rig_workcell
from compare.sensing.scene import (
    arm_qpos_addresses,
    control_point_positions,
    load_workcell,
    make_data,
    set_arm_configuration,
    workcell_path,
)
from compare.sensing.self_filter import SelfFilter, StaticBackground

__all__ = [
    "PERSON_GROUP",
    "ROBOT_VISUAL_GROUP",
    "STATIC_GROUP",
    "DepthCamera",
    "DepthDistance",
    "DepthFusion",
    "DepthNoise",
    "DepthObstacleSource",
    "DepthPipeline",
    "DepthRig",
    "DepthSensingSettings",
    "DistanceResult",
    "FusionSettings",
    "GeometricDistance",
    "GeometricObstacleSource",
    "ObstacleReading",
    "Person",
    "PersonKeyframe",
    "PersonPose",
    "RigObstacleSource",
    "SelfFilter",
    "SensingError",
    "StaticBackground",
    "UnknownSceneElement",
    "arm_qpos_addresses",
    "camera_model_from_mujoco",
    "closest_on_capsules",
    "control_point_positions",
    "deproject",
    "load_rig_workcell",
    "load_workcell",
    "make_data",
    "point_cloud",
    "project",
    "set_arm_configuration",
    "set_camera_look_at",
    "truth_function",
    "valid_fraction",
    "workcell_path",
]

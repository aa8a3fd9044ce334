"""The simulated work cell of a robot: table, depth camera, person, and the arm ready to be driven.

A robot whose spec names a ``workcell`` MJCF of its own (the Jaco²'s ``scene_workcell.xml``)
uses that file. Any other robot is attached at the origin (= its base frame) of the shared cell
``robots/workcell/workcell.xml`` (``environment.xml`` + ``camera_person.xml``), after the changes
a simulation needs and a bare description lacks:

* every arm body gets passive gravity compensation (``gravcomp = 1``), as the Jaco²'s MJCF;
* every joint at least the spec's ``armature`` (a gear's reflected inertia; a URDF has none);
* the description's actuators are replaced by one velocity servo per joint, ``kv`` the spec's
  ``servo_kv``, ``ctrlrange`` ± the robot's velocity limits, ``forcerange`` the joint's effort
  limit: what the ``servo`` joint drive runs; the default ``decoupled`` drive reads only their
  ``ctrlrange`` and disables them;
* geoms follow the cell's groups (``camera_person.xml``): primitives are the arm's visual geoms
  (group 2: rendered by the depth camera, removed by the self-filter); a mesh goes to group 3 and
  gets an enclosing primitive in group 2 (:mod:`robots.proxies`); no arm geom collides;
* the keyframe ``home`` holds the spec's home configuration (the description's keyframes are
  dropped).
"""

from __future__ import annotations

import contextlib
import logging
import warnings
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING

import mujoco
import numpy as np

from robots.description import compile_spec
from robots.proxies import fit_proxy, mesh_vertices, proxy_in_body

if TYPE_CHECKING:
    from robots.robot import Robot

log = logging.getLogger(__name__)

CELL_FILE = Path(__file__).resolve().parent / "workcell" / "workcell.xml"
"""The shared work cell without a robot."""

VISUAL_GROUP = 2
"""Geom group of the arm geoms the depth camera sees and the self-filter removes."""
COLLISION_GROUP = 3
"""Geom group of the arm's mesh geoms (drawn by a viewer only)."""


def prepare_arm(spec: mujoco.MjSpec, robot: Robot) -> None:
    """Turn a description's spec into the arm of a work cell (module docstring), in place."""
    for k, geom in enumerate(spec.geoms):
        if not geom.name:  # URDF geoms have no names; the proxies are matched to their meshes by name
            geom.name = f"{geom.parent.name}_geom_{k}"
    model = compile_spec(spec.copy(), robot.spec.description)  # geom frames and mesh vertices
    for key in list(spec.keys):
        spec.delete(key)
    for actuator in list(spec.actuators):
        spec.delete(actuator)
    for body in spec.bodies:
        if body.name != "world":
            body.gravcomp = 1.0
    for geom in list(spec.geoms):
        geom.contype = 0
        geom.conaffinity = 0
        if geom.type != mujoco.mjtGeom.mjGEOM_MESH:
            geom.group = VISUAL_GROUP
            continue
        geom.group = COLLISION_GROUP
        g = model.geom(geom.name).id
        proxy = fit_proxy(mesh_vertices(model, g))
        pos, quat = proxy_in_body(model, g, proxy)
        stand_in = geom.parent.add_geom()
        stand_in.name = f"{geom.name}_proxy"
        stand_in.type = proxy.kind
        stand_in.size = proxy.size
        stand_in.pos = pos
        stand_in.quat = quat
        stand_in.group = VISUAL_GROUP
        stand_in.contype = 0
        stand_in.conaffinity = 0
        stand_in.density = 0.0
        stand_in.rgba = [0.85, 0.85, 0.88, 1.0]
    for i, name in enumerate(robot.joint_names):
        joint = spec.joint(name)
        joint.armature = max(float(joint.armature), robot.spec.armature)
        act = spec.add_actuator()
        act.name = f"{name}_velocity"
        act.target = name
        act.trntype = mujoco.mjtTrn.mjTRN_JOINT
        act.set_to_velocity(kv=robot.spec.servo_kv)
        v = float(robot.v_max[i])
        act.ctrllimited = True
        act.ctrlrange = [-v, v]
        j = model.joint(name).id
        if model.jnt_actfrclimited[j]:
            act.forcelimited = True
            act.forcerange = model.jnt_actfrcrange[j].copy()


def workcell_spec(robot: Robot) -> mujoco.MjSpec:
    """A fresh spec of the robot's work cell (compile it, or add cameras first)."""
    if robot.spec.workcell is not None:
        return mujoco.MjSpec.from_file(str(robot.spec.workcell))
    cell = mujoco.MjSpec.from_file(str(CELL_FILE))
    arm = robot.mujoco_spec()
    prepare_arm(arm, robot)
    frame = cell.worldbody.add_frame()
    with _empty_prefix_accepted():
        cell.attach(arm, frame=frame, prefix="")
    cell.add_key(name="home", qpos=np.asarray(robot.home, dtype=float))
    return cell


def workcell_model(robot: Robot) -> mujoco.MjModel:
    """The robot's compiled work cell (arm joints are the model's first ``robot.nq`` DoFs)."""
    path = robot.spec.workcell or robot.spec.description
    spec = workcell_spec(robot)
    with _empty_prefix_accepted():
        return compile_spec(spec, path)


_EMPTY_PREFIX = "Attaching a spec with an empty prefix"


@contextlib.contextmanager
def _empty_prefix_accepted() -> Iterator[None]:
    """Silence MuJoCo's note on attaching without a prefix (on purpose: frames keep their own names).

    Any other MuJoCo warning raised meanwhile is logged.
    """

    def handler(message: str) -> None:
        if not message.startswith(_EMPTY_PREFIX):
            log.warning("MuJoCo: %s", message)

    previous = mujoco.get_mju_user_warning()
    mujoco.set_mju_user_warning(handler)
    try:
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message=_EMPTY_PREFIX)
            yield
    finally:
        mujoco.set_mju_user_warning(previous)

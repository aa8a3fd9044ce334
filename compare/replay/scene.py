"""The MuJoCo state of a replayed run at an instant: each method's arm and the shared person.

Each method has its own :class:`mujoco.MjData` in one work-cell model: the arm joints from the
method's step table (the last step at or before the instant), the person's mocap bodies from the
scenario's keyframes at the instant, then ``mj_kinematics``. Nothing is simulated.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numpy as np

from compare.replay.run_data import ReplayRun
from compare.sensing.geometric_distance import closest_on_capsules
from compare.sensing.person import Person
from compare.sensing.rig import load_rig_workcell
from compare.sensing.scene import arm_qpos_addresses, make_data

PERSON_CENTRE_HEIGHT_M = 0.25
"""Height above the table top framed for the person [m] (chest height with the table at z = 0)."""


VIEW_ANGLE_DEG = 40.0
"""Angle between the arm–person line and the view direction [deg]: the arm in front, the person beyond it."""


@dataclass(frozen=True)
class ViewPoint:
    """A free MuJoCo camera: look-at point [m], distance [m], azimuth and elevation [deg]."""

    lookat: tuple[float, float, float]
    distance_m: float
    azimuth_deg: float
    elevation_deg: float

    def apply(self, camera: mujoco.MjvCamera) -> None:
        """Set ``camera`` (made a free camera) to this view."""
        camera.type = mujoco.mjtCamera.mjCAMERA_FREE
        camera.lookat[:] = self.lookat
        camera.distance = self.distance_m
        camera.azimuth = self.azimuth_deg
        camera.elevation = self.elevation_deg


class ReplayScene:
    """One work cell, one ``MjData`` per replayed method, the person shared.

    Args:
        run: The loaded run.
        model: Work-cell model to use (default the run's own: with its depth cameras when it
            sensed with several or configured ones).
    """

    def __init__(self, run: ReplayRun, model: mujoco.MjModel | None = None) -> None:
        self.run = run
        if model is None:
            cameras = run.config.sensor.cameras if run.depth_sensing else []
            model = load_rig_workcell(run.robot.name, cameras) if cameras else run.robot.workcell_model()
        self.model = model
        sc = run.config.scenario
        self.person = Person(model, run.config.person.keyframes, time_scale=sc.time_scale)
        self._arm = arm_qpos_addresses(model)
        self.datas = [make_data(model, m.q[0]) for m in run.methods]

    def set_time(self, t: float) -> list[int]:
        """Pose every method's arm and the person at time ``t`` [s]; returns each method's step index."""
        first = self.datas[0]
        self.person.apply(t, first)
        for data in self.datas[1:]:  # the person is the same in every method's run
            data.mocap_pos[:] = first.mocap_pos
            data.mocap_quat[:] = first.mocap_quat
        return [self._arm_at(i, t) for i in range(len(self.datas))]

    def pose(self, index: int, t: float) -> int:
        """Pose method ``index``'s arm and the person in its data at time ``t`` [s]; returns the step index."""
        self.person.apply(t, self.datas[index])
        return self._arm_at(index, t)

    def _arm_at(self, index: int, t: float) -> int:
        method, data = self.run.methods[index], self.datas[index]
        k = int(method.rows_at([t])[0])
        data.qpos[self._arm] = method.q[k]
        data.time = t
        mujoco.mj_kinematics(self.model, data)
        return k


def control_point_positions(run: ReplayRun, q: np.ndarray) -> np.ndarray:
    """Positions [m] of the run's control points for each configuration of ``q`` (T, n). Shape (T, K, 3)."""
    frames = run.control_points
    out = np.empty((len(q), len(frames), 3))
    for i, qi in enumerate(q):
        kin = run.robot.kinematics(qi)
        for k, frame in enumerate(frames):
            out[i, k] = kin.frame_position(frame)
    return out


def closest_person_points(person: Person, times: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distance [m] (T, K) and closest point on the person [m] (T, K, 3) of ``points`` (T, K, 3) at ``times``."""
    caps = person.capsule_ends(times)
    dist = np.empty(points.shape[:2])
    closest = np.empty(points.shape)
    for i in range(len(times)):
        dist[i], closest[i] = closest_on_capsules(points[i], caps.a[i], caps.b[i], caps.radius)
    return dist, closest


def default_view(run: ReplayRun, person: Person, aspect: float) -> ViewPoint:
    """A view of the arm's workspace and the person over the replayed window.

    The camera looks across the line from the arm's end-effector region to the person's mean
    position (oblique, from the side), far enough to hold both in a panel of width/height ``aspect``.
    """
    ee = np.vstack([m.steps[["ee_x", "ee_y", "ee_z"]].to_numpy(dtype=float) for m in run.methods])
    arm = 0.5 * (np.nanmean(ee, axis=0) + np.zeros(3))  # between the base and the mean EE position
    times = np.linspace(run.t_from, run.t_to, 50)
    centre, span = arm, 1.4
    direction = math.pi / 2.0
    if person.present:
        keys = person.keys_at(times)
        torso = np.array([np.mean(keys[:, 0]), np.mean(keys[:, 1]), PERSON_CENTRE_HEIGHT_M])
        gap = torso[:2] - arm[:2]
        if 0.05 < float(np.linalg.norm(gap)) < 4.0:
            direction = math.atan2(gap[1], gap[0])
            centre = arm + 0.4 * (torso - arm)  # the arm nearer the middle: it is what moves
            span = 1.4 + 0.5 * float(np.linalg.norm(gap))
    vfov = math.radians(45.0)
    hfov = 2.0 * math.atan(aspect * math.tan(vfov / 2.0))
    distance = max(1.6, 0.5 * span / math.tan(min(vfov, hfov) / 2.0))
    azimuth = math.degrees(direction) + VIEW_ANGLE_DEG
    return ViewPoint((float(centre[0]), float(centre[1]), float(centre[2])), distance, azimuth, -28.0)

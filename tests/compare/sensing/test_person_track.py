"""The person's capsules on a time grid, and the distances of points to them."""

from __future__ import annotations

import math

import mujoco
import numpy as np

from compare.sensing.geometric_distance import GeometricDistance
from compare.sensing.person import Person, PersonKeyframe
from compare.sensing.person_track import PersonTrack, capsule_margins
from compare.sensing.scene import load_workcell

Q0 = (4.9, 3.78, 3.392, 1.124, 3.156, 2.03, 0.0)


def test_capsule_margins_match_mujoco_geometry():
    model = load_workcell("jaco2")
    data = mujoco.MjData(model)
    frames = [
        PersonKeyframe(0.0, (0.2, 1.2), -1.4),
        PersonKeyframe(1.0, (0.1, 0.7), -1.6, right_hand=(0.1, 0.3, 0.7)),
    ]
    person = Person(model, frames)
    track = PersonTrack.from_person(person, 1.0, 0.01)
    geometry = GeometricDistance(model, rho_m=math.inf)
    rng = np.random.default_rng(3)
    for t in (0.0, 0.37, 1.0):
        person.apply(t, data)
        mujoco.mj_kinematics(model, data)
        points = rng.uniform([-0.6, -0.6, 0.0], [0.6, 1.0, 1.2], (20, 3))
        truth = geometry.distances(data, {str(i): p for i, p in enumerate(points)})
        margin, _ = capsule_margins(points, *track.at(t))
        np.testing.assert_allclose(np.maximum(margin.min(axis=1), 0.0), [truth[str(i)] for i in range(20)], atol=1e-9)


def test_distance_gradient_matches_finite_differences(jaco):
    a = np.array([[0.3, 0.5, 0.2]])
    b = np.array([[0.1, 0.6, 0.9]])
    r = np.array([0.05])
    rng = np.random.default_rng(0)
    for _ in range(5):
        q = np.array(Q0) + rng.uniform(-0.3, 0.3, 7)

        def dist(qq):
            p = jaco.kinematics(qq).frame_position("link_7")[None, :]
            return float(capsule_margins(p, a, b, r)[0][0, 0])

        kin = jaco.kinematics(q)
        _, normal = capsule_margins(kin.frame_position("link_7")[None, :], a, b, r)
        grad = normal[0, 0] @ kin.position_jacobian("link_7")
        h = 1e-6
        fd = np.array([(dist(q + h * e) - dist(q - h * e)) / (2 * h) for e in np.eye(7)])
        np.testing.assert_allclose(grad, fd, atol=1e-6)

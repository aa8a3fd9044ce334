"""Every distance the metrics judge pairs the arm's state with the person's pose at the same instant."""

from __future__ import annotations

import math

import numpy as np
import pytest

from compare.run import run_method
from compare.sensing.person import Person
from compare.sensing.person_track import capsule_margins
from tests.compare.scenes import CPS, control_point, scene


def _config(jaco, simulation: str):
    p7 = control_point(jaco)
    torso = [float(p7[0]), float(p7[1] + 0.8)]
    # The hand sweeps back and forth past link_7 at ~2 m/s: a one-period offset moves it ~2 cm.
    frames = [{"t": 0.0, "position": torso, "yaw": -math.pi / 2}]
    for k in range(1, 7):
        side = 0.3 if k % 2 else -0.3
        frames.append(
            {"t": 0.3 * k, "position": torso, "yaw": -math.pi / 2, "right_hand": (p7 + [side, 0.3, 0.1]).tolist()}
        )
    return scene(frames, 2.0, simulation=simulation, walls=False)


@pytest.mark.parametrize("simulation", ["dynamic", "kinematic"])
def test_true_distances_pair_the_arm_and_the_person_at_the_same_time(jaco, simulation):
    config = _config(jaco, simulation)
    steps = run_method(config, "tpik", jaco)["steps"]
    person = Person(jaco.workcell_model(), config.person.keyframes)
    t = steps["t"].to_numpy()
    q = steps[[f"q_{j}" for j in range(1, 8)]].to_numpy()
    caps = person.capsule_ends(t)
    expected = np.array(
        [
            capsule_margins(
                np.array([jaco.kinematics(qk).frame_position(f) for f in CPS]), caps.a[k], caps.b[k], caps.radius
            )[0].min(axis=1)
            for k, qk in enumerate(q)
        ]
    )
    recorded = steps[[f"dist_true:{f}" for f in CPS]].to_numpy()
    np.testing.assert_allclose(np.maximum(recorded, 0.0), np.maximum(expected, 0.0), atol=1e-9)
    # The person moves fast enough here that one control period's offset would be seen.
    shifted = np.array(
        [
            capsule_margins(
                np.array([jaco.kinematics(qk).frame_position(f) for f in CPS]),
                caps.a[max(k - 1, 0)],
                caps.b[max(k - 1, 0)],
                caps.radius,
            )[0].min(axis=1)
            for k, qk in enumerate(q)
        ]
    )
    assert np.max(np.abs(shifted - expected)) > 5e-3

"""The reachability certificate: its bounds hold for the arm, it proves unescapable cases, and only those."""

from __future__ import annotations

import math

import numpy as np
import pytest

import robots
from compare.campaign.reachability import ReachableCubes, _structure, prove_unavoidable, reach_bound
from compare.campaign.witness import run_witness
from compare.config import WitnessSpec
from compare.sensing.person import Person, PersonKeyframe
from compare.sensing.person_track import PersonTrack, capsule_margins
from tests.compare.scenes import CPS, scene
from tests.compare.scenes import Q0 as SCENE_Q0

Q0 = np.array(SCENE_Q0)


@pytest.mark.parametrize("robot_name", ["jaco2", "panda", "ur5"])
def test_speed_and_reach_bounds_hold_at_random_configurations_and_velocities(robot_name):
    robot = robots.load(robot_name)
    lo = np.where(np.isfinite(robot.q_lower), robot.q_lower, -math.pi)
    hi = np.where(np.isfinite(robot.q_upper), robot.q_upper, math.pi)
    rng = np.random.default_rng(1)
    for frame in robot.control_points:
        bound = reach_bound(robot, frame)
        tight_speed = tight_reach = 0.0
        for _ in range(300):
            kin = robot.kinematics(rng.uniform(lo, hi))
            qdot = rng.choice([-1.0, 1.0], robot.nq) * robot.v_max  # the corners of the velocity box
            speed = float(np.linalg.norm(kin.position_jacobian(frame) @ qdot))
            reach = float(np.linalg.norm(kin.frame_position(frame) - bound.anchor))
            assert speed <= bound.speed_mps + 1e-9 and reach <= bound.reach_m + 1e-9
            tight_speed, tight_reach = max(tight_speed, speed), max(tight_reach, reach)
        assert tight_speed > 0.3 * bound.speed_mps and tight_reach > 0.6 * bound.reach_m  # bounds, not vacuous


def test_dilation_kernel_takes_the_cubes_within_reach_box_to_box():
    inner = _structure(0.03, 0.04)
    assert inner.sum() == 27 and inner[1:4, 1:4, 1:4].all()  # a move shorter than a cube: the neighbours
    wider = _structure(0.06, 0.04)
    c = wider.shape[0] // 2
    assert wider[c + 2, c, c] and not wider[c + 2, c + 2, c + 2]  # box gaps 0.04 and 0.069 m


def test_the_reachable_cubes_contain_every_sampled_motion_within_the_velocity_limits(jaco):
    """Soundness of the propagation: random velocity-limited motions never leave the cube set."""
    rng = np.random.default_rng(2)
    for frame in CPS:
        bound = reach_bound(jaco, frame)
        reach = ReachableCubes(bound, jaco.kinematics(Q0).frame_position(frame), 0.01, 0.04)
        qs = [Q0.copy() for _ in range(40)]
        qdots = [rng.uniform(-1, 1, 7) * jaco.v_max for _ in qs]
        for step in range(60):
            reach.advance()
            for i in range(len(qs)):
                if step % 10 == 0:
                    qdots[i] = rng.choice([-1.0, 1.0], 7) * jaco.v_max
                qs[i] = qs[i] + qdots[i] * reach.step_s
                assert reach.contains(jaco.kinematics(qs[i]).frame_position(frame)), (frame, step)
        assert not reach.cubes.all()  # still a bounded set


def _dash(jaco, arrive_s: float) -> list[dict]:
    """A hand that starts clear of every threshold and dashes at link_7 in ``arrive_s`` seconds."""
    p7 = jaco.kinematics(Q0).frame_position("link_7")
    torso = [float(p7[0]), float(p7[1] + 0.75)]
    start = p7 + np.array([0.0, 0.5, 0.0])
    return [
        {"t": 0.0, "position": torso, "yaw": -math.pi / 2, "right_hand": start.tolist()},
        {"t": arrive_s, "position": torso, "yaw": -math.pi / 2, "right_hand": p7.tolist()},
        {"t": arrive_s + 0.5, "position": torso, "yaw": -math.pi / 2, "right_hand": p7.tolist()},
    ]


def _start_margin(jaco, config) -> float:
    model = jaco.workcell_model()
    track = PersonTrack.from_person(Person(model, [PersonKeyframe(**f) for f in _frames(config)]), 0.1, 0.01)
    points = np.array([jaco.kinematics(Q0).frame_position(f) for f in CPS])
    return float(capsule_margins(points, *track.at(0.0))[0].min()) - 0.35


def _frames(config) -> list[dict]:
    return [
        {"t": f.t, "position": f.position, "yaw": f.yaw, "right_hand": f.right_hand, "left_hand": f.left_hand}
        for f in config.person.keyframes
    ]


def _certify(jaco, config, frame: str = "link_7"):
    model = jaco.workcell_model()
    track = PersonTrack.from_person(Person(model, config.person.keyframes), config.scenario.sim_time_s + 1.0, 0.01)
    start = jaco.kinematics(Q0).frame_position(frame)
    return prove_unavoidable(reach_bound(jaco, frame), start, track, 0.35, config.scenario.sim_time_s, 0.01)


def test_a_hand_dashing_in_faster_than_any_escape_is_proven_unavoidable_and_no_witness_holds(jaco):
    config = scene(_dash(jaco, 0.1), 1.0, walls=False)
    assert _start_margin(jaco, config) > 0.0  # every control point starts beyond its threshold
    proof = _certify(jaco, config)
    assert proof is not None and 0.0 < proof.time_s <= 0.1 + 1e-9
    for witness in ("oracle-1s", "preview-1s", "preview-0s"):
        assert run_witness(config, jaco, WitnessSpec.parse(witness)).entry["held"] is False


def test_a_slow_hand_that_a_witness_escapes_is_not_proven(jaco):
    config = scene(_dash(jaco, 3.0), 4.0, walls=False)
    assert run_witness(config, jaco, WitnessSpec.parse("preview-1s")).entry["held"] is True
    assert all(_certify(jaco, config, f) is None for f in CPS)

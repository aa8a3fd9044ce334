"""How much room each arm leaves the EE task under active set tasks (docs/robots.md, "The UR5: not redundant").

At each arm's case-2 start pose: the rows of k active obstacle-distance tasks (the paper's partial
Jacobians of the control points, random obstacle directions) stacked on the EE position (3) or
pose (6) Jacobian. The EE task stays exact while the stack has full row rank.
"""

from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np
import pytest

import robots

CONFIGS = Path(__file__).resolve().parents[2] / "configs"
START = {"jaco2": "case2.toml", "panda": "panda_case2.toml", "ur5": "ur5_case2.toml"}
# joints that move the EE position, most active set tasks with the EE position exact, ... with the pose exact
EXPECTED = {"jaco2": (6, 3, 1), "panda": (6, 3, 1), "ur5": (5, 2, 0)}


def _stack_rank(arm: robots.Robot, q: np.ndarray, k: int, ee_rows: slice, rng: np.random.Generator) -> int:
    kin = arm.kinematics(q)
    rows = [kin.frame_jacobian(arm.ee_frame)[ee_rows]]
    for frame in arm.control_points[:k]:
        u = rng.normal(size=3)
        rows.append((u / np.linalg.norm(u)) @ kin.partial_position_jacobian(frame))
    return int(np.linalg.matrix_rank(np.vstack(rows), tol=1e-9))


@pytest.mark.parametrize("name", list(EXPECTED))
def test_active_set_tasks_the_ee_position_and_pose_survive(name):
    arm = robots.load(name)
    with open(CONFIGS / START[name], "rb") as f:
        q = np.array(tomllib.load(f)["scenario"]["start_q"])
    moving, position_room, pose_room = EXPECTED[name]
    kin = arm.kinematics(q)
    jac = kin.position_jacobian(arm.ee_frame)
    assert int(np.count_nonzero(np.linalg.norm(jac, axis=0) > 1e-12)) == moving  # the last joint moves no EE
    rng = np.random.default_rng(0)
    for k in range(len(arm.control_points) + 1):
        position_exact = _stack_rank(arm, q, k, slice(0, 3), rng) == 3 + k
        pose_exact = _stack_rank(arm, q, k, slice(0, 6), rng) == 6 + k
        assert position_exact == (k <= position_room), (name, k)
        assert pose_exact == (k <= pose_room), (name, k)

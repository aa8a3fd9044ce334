"""Equality-only hierarchies: the HQP cascade equals the Siciliano–Slotine null-space solution."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from qp_baseline.hqp import HqpSolver
from tests.conftest import random_configuration
from tests.qp_baseline.helpers import (
    DT,
    SOLVERS,
    reference_rows,
    smallest_level_singular_value,
    ss_reference,
)
from tpik.hierarchy import Hierarchy, Level
from tpik.solver import TpikSettings, TpikSolver
from tpik.tasks import OrientationTask, PositionTask

# The cascade regularises every level with ε‖q̇‖², ε = 1e-9: its answer differs from the
# undamped reference by O(ε/σ_min²)·‖q̇‖. States are drawn with σ_min(J_k N_{k−1}) ≥ 0.05, and
# targets 1–2 cm / 0.05 rad away, so q̇ stays far below the velocity limits (box inactive).
TOLERANCE = 1e-6


def _hierarchies(kin: object, rng: np.random.Generator) -> dict[str, Hierarchy]:
    p_ee = kin.frame_position("end_effector")  # type: ignore[attr-defined]
    p_4 = kin.frame_position("link_4")  # type: ignore[attr-defined]
    rot = kin.frame_rotation("end_effector")  # type: ignore[attr-defined]
    d_rot = pin.exp3(rng.normal(size=3) * 0.03)

    def pos(name: str, frame: str, p: np.ndarray) -> PositionTask:
        return PositionTask(name, frame, 1.0, p + rng.normal(size=3) * 0.01)

    return {
        "position": Hierarchy([Level("ee", (pos("ee", "end_effector", p_ee),))]),
        "position>orientation": Hierarchy(
            [
                Level("ee", (pos("ee", "end_effector", p_ee),)),
                Level("ori", (OrientationTask("ori", "end_effector", 1.0, d_rot @ rot),)),
            ]
        ),
        # 3 + 3 + 3 rows on 7 joints: the last level only gets a 1-D null space.
        "elbow>ee>orientation": Hierarchy(
            [
                Level("elbow", (pos("elbow", "link_4", p_4),)),
                Level("ee", (pos("ee", "end_effector", p_ee),)),
                Level("ori", (OrientationTask("ori", "end_effector", 1.0, d_rot @ rot),)),
            ]
        ),
        # Two tasks stacked in one level (eq. 5).
        "stacked": Hierarchy(
            [
                Level(
                    "both",
                    (pos("ee", "end_effector", p_ee), OrientationTask("ori", "end_effector", 1.0, d_rot @ rot)),
                )
            ]
        ),
    }


def _cases(jaco: object, count: int, seed: int) -> list[tuple[np.ndarray, str, Hierarchy, np.ndarray]]:
    """Well-conditioned random states with their reference solutions."""
    rng = np.random.default_rng(seed)
    cases = []
    while len(cases) < count:
        q = random_configuration(jaco, rng, inset=0.2)  # type: ignore[arg-type]
        kin = jaco.kinematics(q)  # type: ignore[attr-defined]
        for name, hierarchy in _hierarchies(kin, rng).items():
            rows = reference_rows(hierarchy, kin)
            if smallest_level_singular_value(rows, jaco.nq) < 0.05:  # type: ignore[attr-defined]
                continue
            ref = ss_reference(rows, jaco.nq)  # type: ignore[attr-defined]
            if np.any(np.abs(ref) > 0.5 * jaco.v_max):  # type: ignore[attr-defined]
                continue
            cases.append((q, name, hierarchy, ref))
    return cases


@pytest.mark.parametrize("solver", SOLVERS)
@pytest.mark.parametrize("unconstrained_first", [False, True], ids=["backend", "shortcut"])
def test_equality_hierarchy_matches_siciliano_slotine(jaco, solver, unconstrained_first):
    hqp = HqpSolver(jaco, solver, {"unconstrained_first": unconstrained_first})
    for q, name, hierarchy, ref in _cases(jaco, 12, seed=3):
        result = hqp.solve(hierarchy, jaco.kinematics(q), DT)
        assert result.ok, result.message
        err = np.max(np.abs(result.qdot - ref))
        assert err < TOLERANCE, f"{solver} on {name}: |q̇ − q̇_SS| = {err:.2e}"
        if not unconstrained_first:
            assert result.extras["qp_calls"] >= 1  # the backend itself produced the answer


def test_equality_hierarchy_reports_zero_slack_and_empty_active_set(jaco):
    q, _, hierarchy, _ = _cases(jaco, 1, seed=5)[0]
    result = HqpSolver(jaco, "daqp").solve(hierarchy, jaco.kinematics(q), DT)
    assert result.status.value == "ok"
    assert result.active_set == ()
    assert result.extras["slacks"] == {}
    assert result.build_time_s > 0.0 and result.solve_time_s >= 0.0


def test_zero_velocity_when_all_tasks_satisfied(jaco):
    kin = jaco.kinematics(jaco.home)
    hierarchy = Hierarchy([Level("ee", (PositionTask("ee", "end_effector", 1.0, kin.frame_position("end_effector")),))])
    for solver in SOLVERS:
        result = HqpSolver(jaco, solver, {"unconstrained_first": False}).solve(hierarchy, kin, DT)
        assert np.max(np.abs(result.qdot)) < 1e-7, solver


def test_matches_tpik_siciliano_slotine_variant(jaco):
    tpik = TpikSolver(jaco, TpikSettings(variant="ss"), name="tpik-ss")
    hqp = HqpSolver(jaco, "daqp", {"unconstrained_first": False})
    for q, name, hierarchy, ref in _cases(jaco, 8, seed=11):
        kin = jaco.kinematics(q)
        ours = hqp.solve(hierarchy, kin, DT)
        theirs = tpik.solve(hierarchy, kin, DT)
        assert theirs.ok, theirs.message
        assert np.max(np.abs(theirs.qdot - ref)) < TOLERANCE, f"tpik-ss on {name}"
        assert np.max(np.abs(ours.qdot - theirs.qdot)) < TOLERANCE, f"hqp vs tpik-ss on {name}"

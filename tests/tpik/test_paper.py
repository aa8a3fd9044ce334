"""``tpik-paper`` against an independent re-implementation of the paper's algorithm, and the deviations.

The reference below is written from the paper (sec. II, eqs. 2–9 and sec. II-A) and docs/design.md §3
step by step with NumPy's SVD, in joint space, without any code of ``tpik``: CLIK references
without a gain cap (eq. 2), every subset of the candidate set tasks inserted at its own level with
σ_d the crossed safety threshold (eq. 7), the NSB cascade of eq. 4 with exact null-space projectors
of the augmented Jacobians (eqs. 5–6), damped least squares with the dynamic damping of sec. II-A
and σ* = ‖σ̃‖/‖q̇‖_max, admissibility by eqs. 8–9 alone, the largest-norm admissible mode (ties to
fewer active tasks), and one scale factor into the joint velocity limits.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from compare.methods import ABLATION_PREFIX, ablation_methods, make_method, tpik_presets
from tests.tpik.conftest import MatrixTask, RowSetTask, dynamic_damping, one_level_each
from tpik.hierarchy import Hierarchy, Level
from tpik.solver import DEVIATIONS, PAPER_SETTINGS, TpikSettings, TpikSolver
from tpik.tasks import SetTask, Thresholds

DT = 0.01
TH = Thresholds(-1.5, -1.0, 1.0, 1.5, 0.1)  # activation at ±0.9


def paper_dls(J: np.ndarray, x: np.ndarray, error_norm: float, vnorm: float) -> np.ndarray:
    """J^# x with the damping of sec. II-A: λ from σ_min(J) and σ* = ‖σ̃‖ / ‖q̇‖_max."""
    U, s, Vt = np.linalg.svd(J, full_matrices=False)
    sigma_min = float(s.min()) if J.shape[0] <= J.shape[1] else 0.0
    lam = dynamic_damping(sigma_min, error_norm / vnorm)
    keep = s > 1e-6
    return Vt[keep].T @ ((s[keep] / (s[keep] ** 2 + lam**2)) * (U[:, keep].T @ x))


def null_projector(J: np.ndarray) -> np.ndarray:
    """I − J†J of the augmented Jacobian (eq. 6), from its SVD."""
    _, s, Vt = np.linalg.svd(J, full_matrices=True)
    rank = int(np.count_nonzero(s > 1e-6))
    V = Vt[:rank]
    return np.eye(J.shape[1]) - V.T @ V


def paper_step(levels: list[dict], v_max: np.ndarray) -> tuple[np.ndarray, set[str]]:
    """One step of the paper's algorithm; ``levels``: per level {"eq": [(J, x, e)], "set": [(name, σ, J, K)]}.

    Returns q̇ [rad/s] and the inserted set tasks.
    """
    n = v_max.shape[0]
    vnorm = float(np.linalg.norm(v_max))
    candidates = []  # (level, name, side, row, x, e)
    for k, level in enumerate(levels):
        for name, sigma, row, gain in level["set"]:
            if sigma >= TH.activation_upper:
                side, target = 1.0, TH.safety_upper
            elif sigma <= TH.activation_lower:
                side, target = -1.0, TH.safety_lower
            else:
                continue
            candidates.append((k, name, side, row, gain * (target - sigma), target - sigma))
    # Level-major enumeration: the first level's candidates vary slowest, bit j = its j-th candidate.
    per_level = [[c for c in candidates if c[0] == k] for k in range(len(levels))]
    best = None
    for choice in itertools.product(*[list(itertools.product([False, True], repeat=len(cs))) for cs in per_level]):
        inserted = {
            c[1] for cs, bits in zip(per_level, choice, strict=True) for c, on in zip(cs, bits[::-1], strict=True) if on
        }
        qdot = np.zeros(n)
        above = np.zeros((0, n))
        for k, level in enumerate(levels):
            rows = [(J, x, e) for J, x, e in level["eq"]]
            rows += [(c[3][None, :], np.array([c[4]]), np.array([c[5]])) for c in per_level[k] if c[1] in inserted]
            if not rows:
                continue
            J = np.vstack([r[0] for r in rows])
            x = np.concatenate([r[1] for r in rows])
            e = np.concatenate([r[2] for r in rows])
            qdot = (
                qdot + null_projector(above) @ paper_dls(J, x, float(np.linalg.norm(e)), vnorm)
                if above.size
                else qdot + paper_dls(J, x, float(np.linalg.norm(e)), vnorm)
            )
            above = np.vstack([above, J])
        admissible = all(c[1] in inserted or c[2] * float(c[3] @ qdot) <= 1e-9 for c in candidates)  # eqs. 8–9
        if not admissible:
            continue
        norm2 = float(qdot @ qdot)
        if best is not None:
            close = abs(norm2 - best[0]) <= 1e-12 * (1.0 + max(norm2, best[0]))
            better = len(inserted) < len(best[2]) if close else norm2 > best[0]
            if not better:
                continue
        best = (norm2, qdot, inserted)
    assert best is not None  # S = C is always admissible
    qdot = best[1]
    ratio = float(np.max(np.abs(qdot) / v_max))
    return (qdot / ratio if ratio > 1.0 else qdot), best[2]


def random_problem(rng: np.random.Generator, n: int) -> tuple[Hierarchy, list[dict]]:
    """2–4 levels of random equality rows and set tasks near, past or far from their thresholds."""
    levels, description, count = [], [], 0
    for k in range(int(rng.integers(2, 5))):
        tasks, spec = [], {"eq": [], "set": []}
        for _ in range(int(rng.integers(0, 3))):
            sigma = float(rng.choice([rng.uniform(0.86, 1.08), -rng.uniform(0.86, 1.08), rng.uniform(-0.5, 0.5)]))
            row = rng.normal(size=n) * (0.05 if rng.random() < 0.15 else 1.0)  # some nearly singular
            gain = float(rng.choice([1.0, 2.0, rng.uniform(0.5, 300.0)]))  # > 1/dt: no cap in the paper
            name = f"s{count}"
            count += 1
            tasks.append(RowSetTask(name, sigma, row, TH, gain=gain))
            spec["set"].append((name, sigma, row, gain))
        if rng.random() < 0.7 or not tasks:
            m = int(rng.integers(1, 4))
            J = rng.normal(size=(m, n)) * (0.05 if rng.random() < 0.15 else 1.0)
            error = rng.normal(size=m) * rng.choice([0.01, 0.3, 2.0])
            gain = float(rng.choice([1.0, rng.uniform(0.5, 300.0)]))
            name = f"eq{count}"
            count += 1
            tasks.insert(0, MatrixTask(name, J, error, gain=gain))
            spec["eq"].append((J, gain * error, error))
        levels.append(Level(f"level_{k}", tuple(tasks)))
        description.append(spec)
    return Hierarchy(levels), description


def test_tpik_paper_is_the_papers_algorithm_on_400_random_states(jaco):
    rng = np.random.default_rng(15)
    solver = make_method("tpik-paper", jaco)
    kin = jaco.kinematics(jaco.home)
    inserted_somewhere = left_out_somewhere = 0
    for _ in range(400):
        hierarchy, levels = random_problem(rng, jaco.nq)
        qdot, report = solver.solve(hierarchy, kin, DT)
        expected, inserted = paper_step(levels, np.asarray(jaco.v_max, dtype=float))
        np.testing.assert_allclose(qdot, expected, rtol=0.0, atol=1e-9)
        assert set(report.active_set) == inserted
        inserted_somewhere += bool(inserted)
        left_out_somewhere += report.extras["candidates"] > len(inserted)
    assert inserted_somewhere > 100 and left_out_somewhere > 100  # both branches of eqs. 7–9 exercised


def test_paper_settings_switch_every_deviation_back_and_tpik_keeps_them_all():
    paper, default = TpikSettings.from_dict(PAPER_SETTINGS), TpikSettings()
    assert paper.deviations == () and set(default.deviations) == set(DEVIATIONS)
    assert paper.variant == "nsb" and paper.selection == "largest_norm" and not paper.compensate_set_tasks
    assert not paper.return_rate_condition and not paper.gain_cap and paper.damping_sigma_star == "task_error"


@pytest.mark.parametrize("deviation", list(DEVIATIONS))
def test_each_ablation_method_switches_exactly_one_deviation_off(jaco, deviation):
    solver = make_method(f"{ABLATION_PREFIX}{deviation}", jaco)
    assert set(DEVIATIONS) - set(solver.settings.deviations) == {deviation}
    assert f"{ABLATION_PREFIX}{deviation}" in ablation_methods() and f"{ABLATION_PREFIX}{deviation}" in tpik_presets()


def test_gain_cap_is_the_one_difference_of_a_large_gain(jaco):
    """Gain 500 /s, 1 mrad: capped at 1/dt the reference is 0.1 rad/s, uncapped 0.5 rad/s (paper)."""
    task = MatrixTask("q1", np.eye(jaco.nq)[:1], np.array([0.001]), gain=500.0)
    kin = jaco.kinematics(jaco.home)
    capped, _ = TpikSolver(jaco).solve(one_level_each(task), kin, DT)
    uncapped, report = make_method(f"{ABLATION_PREFIX}gain-cap", jaco).solve(one_level_each(task), kin, DT)
    assert 0.5 < jaco.v_max[0] and report.extras["velocity_scale"] == 1.0
    assert capped[0] == pytest.approx(0.1, rel=1e-9) and uncapped[0] == pytest.approx(0.5, rel=1e-9)


def test_return_rate_condition_is_what_keeps_a_violated_task_held(jaco):
    """σ = 1.05 past σ_{s,u} = 1; nothing pushes it: with the condition it is held (comes back), without not."""
    row = np.eye(jaco.nq)[2]
    h = one_level_each(RowSetTask("s", 1.05, row, TH), MatrixTask("still", row[None, :], np.array([0.0])))
    kin = jaco.kinematics(jaco.home)
    qdot, held = TpikSolver(jaco).solve(h, kin, DT)
    _, released = make_method(f"{ABLATION_PREFIX}return-rate", jaco).solve(h, kin, DT)
    assert held.active_set == ("s",) and qdot[2] == pytest.approx(-0.05)
    assert released.active_set == ()


def test_sigma_star_from_the_task_error_damps_less_with_a_gain_above_one(jaco):
    """K = 5 /s: σ* from the reference is 5× the paper's σ* from σ̃, so λ differs (sec. II-A)."""
    J = np.zeros((1, jaco.nq))
    J[0, 0] = 0.5
    task = MatrixTask("weak", J, np.array([0.6]), gain=5.0)  # reference 3 m/s; ‖q̇‖_max ≈ 2.x rad/s
    kin = jaco.kinematics(jaco.home)
    _, ref = TpikSolver(jaco).solve(one_level_each(task), kin, DT)
    _, err = make_method(f"{ABLATION_PREFIX}reference-damping", jaco).solve(one_level_each(task), kin, DT)
    vnorm = float(np.linalg.norm(jaco.v_max))
    assert ref.damping["level_0"] == pytest.approx(dynamic_damping(0.5, 3.0 / vnorm))
    assert err.damping["level_0"] == pytest.approx(dynamic_damping(0.5, 0.6 / vnorm))
    assert err.damping["level_0"] < ref.damping["level_0"]


def test_tpik_paper_is_exhaustive_over_the_twelve_set_tasks_of_case_2(jaco):
    assert make_method("tpik-paper", jaco).settings.max_exhaustive_candidates == 12
    assert isinstance(next(iter(make_method("tpik", jaco).settings.deviations)), str)
    assert not isinstance(TH, SetTask) and math.isfinite(TH.activation_upper)

"""The stored lexicographic reference of the bench: current, reproducible, and never beaten by a cascade."""

from __future__ import annotations

import json

import numpy as np
import pytest

from compare.bench.correctness import compare_levels
from compare.bench.qp_reference import (
    REFERENCE_FILE,
    ReferenceMismatch,
    bench_states,
    compute_reference,
    fingerprint,
    load_reference,
)
from compare.bench.qp_states import RANDOM_COUNT, apply_qp_state, random_states
from compare.bench.solver_cases import case2_hierarchy
from qp_baseline.hqp import HqpSolver
from qp_baseline.lexicographic import level_objectives, level_rows


@pytest.fixture(scope="module")
def stored():
    return load_reference()  # raises ReferenceMismatch when stale


def test_the_stored_reference_covers_the_case2_states_and_the_random_set(stored):
    names = [e.state.name for e in stored]
    assert names[:3] == ["case2-active0", "case2-active1", "case2-active3"]
    assert len(names) == 3 + RANDOM_COUNT >= 203 and len(set(names)) == len(names)
    assert max(e.kkt for e in stored) < 1e-9  # every level QP's optimality conditions, as stored


def test_the_stored_states_are_the_generators(stored, jaco):
    fresh = bench_states(jaco)
    for entry, state in zip(stored, fresh, strict=True):
        assert entry.state.name == state.name and entry.state.dt == state.dt
        np.testing.assert_array_equal(entry.state.bench.q, state.bench.q)


def test_a_recomputed_reference_equals_the_stored_one(stored, jaco):
    sample = [stored[i] for i in (0, 2, 3, 57, 120, 202)]
    again = compute_reference(jaco, [e.state for e in sample])
    for old, new in zip(sample, again, strict=True):
        np.testing.assert_allclose(np.sqrt(new.objectives), np.sqrt(old.objectives), atol=1e-7, rtol=1e-7)


def test_a_changed_state_set_is_refused(tmp_path, jaco):
    data = json.loads(REFERENCE_FILE.read_text(encoding="utf-8"))
    data["fingerprint"] = fingerprint(random_states(jaco, 3, seed=1), jaco)
    stale = tmp_path / "stale.json"
    stale.write_text(json.dumps(data), encoding="utf-8")
    with pytest.raises(ReferenceMismatch, match="regenerate"):
        load_reference(stale)
    assert len(load_reference(stale, check=False)) == len(data["states"])


@pytest.mark.parametrize("index", [3, 40, 88, 150])
def test_no_exact_cascade_beats_the_reference_at_the_first_differing_level(stored, jaco, index):
    """Lexicographic optimality of the reference, checked against DAQP (an exact active-set solver):
    the cascade may win a level only after losing at most its tolerance at the levels above."""
    entry = stored[index]
    hierarchy = case2_hierarchy(jaco)
    apply_qp_state(hierarchy, entry.state)
    kin = jaco.kinematics(entry.state.bench.q)
    rows = level_rows(hierarchy, kin, entry.state.dt)
    result = HqpSolver(jaco, "daqp").solve(hierarchy, kin, entry.state.dt)
    mine = level_objectives(rows, result.qdot)
    strict = compare_levels(mine, entry.objectives, tol=1e-9)
    if strict.verdict == "better":
        assert strict.level is not None
        assert np.all(strict.errors[: strict.level] >= -1e-9)  # no level above it was won
        assert np.any(strict.errors[: strict.level] > 0) or strict.errors[strict.level] > -1e-5

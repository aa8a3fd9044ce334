"""The bench's split of a timed step: core (QP solver / compiled step), build, rows, rest — in the same calls.

Not a timing assertion: the parts are measured inside each timed call, so none may exceed the
call and together they must cover most of it; mink-native's call is its three parts and a
division, so they cover nearly all of it.
"""

from __future__ import annotations

import numpy as np
import pytest

from compare.bench.solver_cases import apply_state, case2_hierarchy, case2_states
from compare.bench.solvers import (
    DT,
    REFERENCE,
    SPLIT,
    build_methods,
    call_split,
    interleaved,
    native_for,
    run_solver_bench,
)
from compare.bench.suite import RATIO_CAPTION, solver_table

METHODS = ("tpik", "hqp-daqp", "mink", "mink-posture")


@pytest.fixture(scope="module")
def splits(jaco) -> dict[str, list[dict[str, float]]]:
    """Per-call splits of every method and mink-native on two case-2 states (15 timed calls each)."""
    solvers = build_methods(METHODS, jaco)
    out: dict[str, list[dict[str, float]]] = {name: [] for name in (REFERENCE, *METHODS)}
    for state in case2_states(jaco)[1:]:
        hierarchies = {name: case2_hierarchy(jaco) for name in solvers}
        for h in hierarchies.values():
            apply_state(h, state)
        native = native_for(jaco, hierarchies["tpik"])

        def native_call(native=native, q=state.q) -> object:  # type: ignore[no-untyped-def]
            native.step(q, DT)
            return native.parts_s

        fns = {REFERENCE: native_call}
        for name, solver in solvers.items():
            fns[name] = lambda s=solver, h=hierarchies[name], q=state.q: s.solve(h, jaco.kinematics(q), DT)
        outputs: dict[str, list[object]] = {name: [] for name in fns}
        samples = interleaved(fns, 15, outputs=outputs)
        for name, us in samples.items():
            assert len(outputs[name]) == len(us) == 15
            out[name] += [call_split(float(t), o) for t, o in zip(us, outputs[name], strict=True)]
    return out


@pytest.mark.parametrize("name", (REFERENCE, *METHODS))
def test_the_parts_lie_inside_each_call_and_cover_most_of_it(splits, name):
    for sp in splits[name]:
        assert min(sp["core_us"], sp["build_us"], sp["rows_us"]) >= 0.0
        assert sp["rest_us"] >= -0.5  # the three parts never add up to more than the call
        assert sp["core_us"] > 0.0
    total = np.array([sum(sp[k] for k in SPLIT) for sp in splits[name]])
    covered = np.median([1.0 - sp["rest_us"] / t for sp, t in zip(splits[name], total, strict=True)])
    assert covered >= (0.9 if name == REFERENCE else 0.4)


def test_rows_are_split_off_for_mink_and_belong_to_the_build_or_core_elsewhere(splits):
    for name in (REFERENCE, "mink", "mink-posture"):
        assert all(sp["rows_us"] > 0.0 for sp in splits[name])
    for name in ("tpik", "hqp-daqp"):
        assert all(sp["rows_us"] == 0.0 for sp in splits[name])


def test_every_ratio_row_carries_the_split_and_the_table_says_what_the_ratio_compares(jaco):
    rows = run_solver_bench(["tpik", "mink"], repeats=5)
    for row in rows:
        assert set(SPLIT) <= set(row.extra)
        parts = sum(row.extra[k] for k in SPLIT[:3])
        assert 0.0 < row.extra["core_us"] <= parts and 0.0 < row.extra["core_fraction"] < 1.0
        assert row.extra["ratio_to_mink"] > 0.0 and row.extra["core_ratio_to_mink"] > 0.0
    assert all(r.extra["core_ratio_to_mink"] == 1.0 for r in rows if r.name == REFERENCE)
    table = solver_table(rows, "case 2")
    assert table.caption == RATIO_CAPTION and "not one algorithm against another" in RATIO_CAPTION
    headers = {str(c.header) for c in table.columns}
    assert {"core [µs]", "core × mink", "build [µs]", "rows [µs]", "rest [µs]"} <= headers

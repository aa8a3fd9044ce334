"""Sensing wired the way the harness uses it: simulated robot I/O, a scripted person, the benchmark."""

from __future__ import annotations

import math

import numpy as np
import pytest

from compare.sensing import (
    DepthPipeline,
    GeometricDistance,
    GeometricObstacleSource,
    Person,
    PersonKeyframe,
    load_workcell,
    truth_function,
)


@pytest.mark.rendering
def test_person_steps_in_and_out_of_range_through_sim_io(jaco):
    from compare.loop.sim_io import SimRobotIO

    model = load_workcell()
    # Stands 1.35 m away, steps in with the right hand raised at t = 0.3 s, leaves at t = 0.9 s.
    person = Person(
        model,
        [
            PersonKeyframe(0.0, (0.0, 1.35), -math.pi / 2),
            PersonKeyframe(0.3, (0.0, 1.35), -math.pi / 2),
            PersonKeyframe(0.5, (0.05, 0.95), -math.pi / 2, right_hand=(0.0, 0.45, 0.75)),
            PersonKeyframe(0.9, (0.05, 0.95), -math.pi / 2, right_hand=(0.0, 0.45, 0.75)),
            PersonKeyframe(1.1, (0.0, 1.35), -math.pi / 2),
        ],
    )
    pipeline = DepthPipeline(model)
    io = SimRobotIO(model, jaco.nq, 0.01, jaco.home, scene_update=person.apply, depth_camera=pipeline.render)
    cps = jaco.control_points
    depth_source = pipeline.source(io.read_depth, cps)
    geometric_source = GeometricObstacleSource(GeometricDistance(model), io.data, cps)
    truth = truth_function(model, io.data, cps)
    near = {"depth": [], "geometric": [], "truth": []}
    try:
        for _ in range(120):
            kin = jaco.kinematics(io.read_joints().q)
            depth = depth_source.update(io.now(), kin)
            geometric = geometric_source.update(io.now(), kin)
            assert not depth.blind
            near["depth"].append(min(depth.distances().values()))
            near["geometric"].append(min(geometric.distances().values()))
            near["truth"].append(min(truth(kin).values()))
            io.send_velocity(np.zeros(jaco.nq))
            io.wait()
    finally:
        pipeline.close()
    for key in near:
        near[key] = np.array(near[key])
    t = np.arange(120) * 0.01
    standing, inside = t < 0.3, (t > 0.55) & (t < 0.85)
    assert np.all(np.isinf(near["depth"][standing])) and np.all(np.isinf(near["geometric"][standing]))
    assert np.all(near["truth"][inside] < 0.5) and np.all(near["depth"][inside] < 0.5)
    # the depth estimate (one frame per 1/30 s, held in between) tracks the geometry
    assert np.all(np.abs(near["depth"][inside] - near["truth"][inside]) < 0.03)
    assert np.all(np.isinf(near["depth"][t > 1.15]))
    assert set(depth.readings) == set(cps)


@pytest.mark.rendering
def test_sensing_bench_reports_the_design_rows():
    from compare.bench.sensing import run_sensing_bench

    all_rows = run_sensing_bench(repeats=10)
    rows = {row.name: row for row in all_rows if row.case == "512x424-rho0.5"}
    for name in ("depth-render", "self-filter", "depth-distance", "depth-kdtree-baseline"):
        assert rows[name].median_us > 0 and rows[name].samples >= 10
    assert rows["depth-distance"].extra["max_error_vs_geometry_m"] < 0.01
    assert rows["depth-kdtree-baseline"].extra["max_diff_vs_depth_distance_m"] < 1e-6
    # Two cameras: each row next to its one-camera counterpart of the same run.
    two = {row.name: row for row in all_rows if row.case == "2x512x424-rho0.5"}
    assert set(two) == {"depth-distance", "depth-sensing-step", "depth-frame"}
    assert {"depth-sensing-step", "depth-frame"} <= set(rows)
    for row in two.values():
        assert row.median_us > 0 and row.extra["ratio_vs_one_camera"] > 0
    # Camera 2 sees the arm behind the person: the space there is unknown to both cameras, so the
    # fused readings may be conservative (nearer), never farther than the truth.
    assert two["depth-distance"].extra["max_over_estimate_vs_geometry_m"] < 0.01

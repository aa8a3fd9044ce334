"""The .rrd read back with rerun's own reader: entities, one timeline, series equal to the step tables."""

from __future__ import annotations

from collections import defaultdict

import numpy as np
import pytest
from rerun.chunk import RrdReader
from typer.testing import CliRunner

from compare.cli import app
from compare.replay.run_data import load_run

pytestmark = pytest.mark.rendering

T_FROM, T_TO = 1.0, 2.0


@pytest.fixture(scope="module")
def recording(case2_run, tmp_path_factory):
    out = tmp_path_factory.mktemp("rrd") / "case2.rrd"
    args = ["replay", str(case2_run), "--rerun", str(out), "--from", str(T_FROM), "--to", str(T_TO), "-q"]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 0, result.output
    chunks = defaultdict(list)
    for chunk in RrdReader(out).stream().collect().stream():
        chunks[chunk.entity_path].append(chunk)
    return chunks


def _column(chunks, path: str, component: str) -> tuple[np.ndarray, list]:
    """Times [s] and values of one component of an entity, in time order."""
    times, values = [], []
    for chunk in chunks[path]:
        batch = chunk.to_record_batch()
        if component not in batch.schema.names:
            continue
        times.extend(batch.column("time").cast("int64").to_numpy() / 1e9)
        values.extend(batch.column(component).to_pylist())
    order = np.argsort(times)
    return np.asarray(times)[order], [values[i] for i in order]


def test_the_recording_has_the_3d_entities_of_every_method(recording):
    for method in ("tpik", "mink"):
        assert f"/world/{method}/control_points" in recording
        assert f"/world/{method}/closest" in recording
        assert f"/world/{method}/depth/depth_camera" in recording
        assert any(p.startswith(f"/world/{method}/arm/") for p in recording)
    for path in ("/world/person", "/world/scene/table/table_top", "/world/cameras/depth_camera"):
        assert path in recording


def test_every_time_varying_entity_is_on_the_one_timeline(recording):
    timelines = {tuple(c.timeline_names) for chunks in recording.values() for c in chunks if not c.is_static}
    assert timelines == {("time",)}


def test_the_time_series_equal_the_step_tables(recording, case2_run):
    run = load_run(case2_run)
    for method in run.methods:
        rows = (method.t >= T_FROM - 1e-9) & (method.t < T_TO - 1e-9)
        t, solve = _column(recording, f"/plots/solve_time_us/{method.name}", "Scalars:scalars")
        np.testing.assert_allclose(t, method.t[rows], atol=1e-6)
        np.testing.assert_allclose([v[0] for v in solve], method.steps["solve_time_us"][rows])
        for frame in run.control_points:
            _, meas = _column(recording, f"/plots/distance/{frame}/{method.name}/measured", "Scalars:scalars")
            expected = method.steps[f"dist_meas:{frame}"][rows].to_numpy(dtype=float)
            got = np.array([v[0] for v in meas], dtype=float)
            np.testing.assert_allclose(got[np.isfinite(expected)], expected[np.isfinite(expected)])
            assert f"/plots/distance/{frame}/{method.name}/true" in recording
        for name in ("obstacle_link_7", "wall_z_min", "joint_limit_4"):
            _, on = _column(recording, f"/plots/active/{method.name}/{name}", "Scalars:scalars")
            assert [v[0] for v in on] == method.steps[f"active:{name}"][rows].astype(float).tolist()
        _, status = _column(recording, f"/plots/status/{method.name}", "Scalars:scalars")
        assert {v[0] for v in status} <= {0.0, 1.0, 2.0}
    _, safety = _column(recording, "/plots/distance/link_7/safety", "Scalars:scalars")
    assert [v[0] for v in safety] == pytest.approx([0.35, 0.35])


def test_the_person_moves_at_the_control_rate_and_the_depth_clouds_at_the_camera_rate(recording):
    t, lengths = _column(recording, "/world/person", "Capsules3D:lengths")
    assert len(t) == 100 and len(lengths[0]) == 10  # 1 s at 100 Hz; torso, head, two legs, 2 x 3 arm segments
    t_depth, points = _column(recording, "/world/tpik/depth/depth_camera", "Points3D:positions")
    assert len(t_depth) == 30  # 1 s at the Kinect's 30 Hz
    assert max(len(p) for p in points) > 50  # the person (and the arm) in front of the background
    t_cp, cps = _column(recording, "/world/mink/control_points", "Points3D:colors")
    assert len(t_cp) == 100 and all(len(c) == 3 for c in cps)


def test_the_arm_is_posed_from_the_recorded_joint_angles(recording, case2_run):
    """The end-effector body of the recording is where the run recorded its end effector."""
    run = load_run(case2_run)
    for method in run.methods:
        t, translation = _column(
            recording, f"/world/{method.name}/arm/j2s7s300_end_effector", "Transform3D:translation"
        )
        recorded = method.steps[["ee_x", "ee_y", "ee_z"]].to_numpy()[method.rows_at(t)]
        np.testing.assert_allclose(np.array([v[0] for v in translation]), recorded, atol=1e-5)

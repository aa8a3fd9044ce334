"""Paper-style figures: one column per method, every column on the same axes."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from compare.analysis.paper_figures import paper_figures, plot_paper_figures
from compare.analysis.results import ResultsWriter

CONFIGS = Path(__file__).resolve().parents[3] / "configs"


def _steps(shift: float) -> pd.DataFrame:
    t = np.round(np.arange(0.0, 70.0, 0.05), 10)
    near = (t > 36.0) & (t < 55.0)
    d = np.where(near, 0.36 + shift, 0.8)
    cols = {
        "t": t,
        "ee_x": 0.5 * np.sin(0.3 * t),
        "ee_y": 0.4,
        "ee_z": 0.7,
        "ee_error_m": np.abs(np.cos(0.3 * t)),
        "waypoint": (t > 30).astype(int),
        **{f"sigma:joint_limit_{j}": 2.0 + 0.1 * np.sin(t) for j in (2, 4, 6)},
    }
    for cp in ("link_4", "link_6", "link_7"):
        cols[f"sigma:obstacle_{cp}"] = d
        cols[f"truth:obstacle_{cp}"] = d
        cols[f"dist_true:{cp}"] = d
        cols[f"dist_meas:{cp}"] = d + 0.01
    return pd.DataFrame(cols)


@pytest.fixture
def case1_run(tmp_path) -> Path:
    run = tmp_path / "run"
    text = (CONFIGS / "case1.toml").read_text()
    writer = ResultsWriter(run, "case1", 0, 70.0, text)
    for k, name in enumerate(("tpik", "hqp-daqp", "mink")):
        writer.add_method(name, {"scenario": "case1"}, _steps(0.02 * k))
    return run


def test_case1_figures_put_the_methods_side_by_side_on_shared_axes(case1_run):
    figures = paper_figures(case1_run)
    assert set(figures) == {"paper_fig3_ee_error", "paper_fig4_distances", "paper_fig5_joints", "paper_ee_path"}
    fig4 = figures["paper_fig4_distances"]
    axes = np.array(fig4.axes).reshape(3, 3)  # control points × methods
    assert [ax.get_title() for ax in axes[0]] == ["tpik", "hqp-daqp", "mink"]
    for row in axes:
        assert all(row[0].get_shared_y_axes().joined(row[0], ax) for ax in row[1:])
        assert all(row[0].get_ylim() == ax.get_ylim() for ax in row[1:])
    assert all(axes[0, 0].get_shared_x_axes().joined(axes[0, 0], ax) for ax in axes.flat)
    fig3 = figures["paper_fig3_ee_error"]
    assert len(fig3.axes) == 3 and len({ax.get_ylim() for ax in fig3.axes}) == 1
    paths = plot_paper_figures(case1_run)
    assert {p.name for p in paths} == {f"{n}.png" for n in figures}
    assert all(p.stat().st_size > 10_000 for p in paths)


def test_case2_figures_and_non_case_runs(tmp_path, case1_run):
    run = tmp_path / "case2"
    shutil.copytree(case1_run, run)
    (run / "config.toml").write_text((CONFIGS / "case2.toml").read_text())
    steps = _steps(0.0)
    for name in ("tpik", "hqp-daqp", "mink"):
        for wall, value in (("wall_z_min", steps["ee_z"] - 0.2), ("wall_x_max", 0.5 - steps["ee_x"])):
            steps[f"sigma:{wall}"] = value
        steps.to_parquet(run / "steps" / f"{name}.parquet")
    figures = paper_figures(run)
    assert set(figures) == {"paper_fig8_ee_walls", "paper_fig9_distances", "paper_fig10_joints"}
    assert len(figures["paper_fig8_ee_walls"].axes) == 9
    # A distance above the paper's 1.2 m stays in view, and only lines drawn get a legend entry.
    far = steps.assign(**{"dist_true:link_4": 1.39, "dist_meas:link_4": np.inf, "dist_meas:link_6": np.inf})
    far = far.assign(**{"dist_meas:link_7": np.inf})
    for name in ("tpik", "hqp-daqp", "mink"):
        far.to_parquet(run / "steps" / f"{name}.parquet")
    fig9 = paper_figures(run)["paper_fig9_distances"]
    assert all(ax.get_ylim()[1] >= 1.39 for ax in fig9.axes)
    legend = [t.get_text() for t in fig9.axes[0].get_legend().get_texts()]
    assert "true" in legend and "measured" not in legend
    (run / "config.toml").write_text((CONFIGS / "random.toml").read_text())
    assert paper_figures(run) == {}

"""Plots and report: files exist, are real PNGs of sensible size, and the report links them."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from matplotlib.image import imread
from rich.console import Console

from compare.analysis.metrics import compute_summary
from compare.analysis.plots import plot_run, plot_sweep, wall_axis
from compare.analysis.report import summary_table
from compare.analysis.results import ResultsWriter, load_summary, sweep_run_dir
from tests.compare.analysis.test_metrics import WALL_X_MAX, make_meta, make_steps

MIN_PNG_BYTES = 8_000


def _busy_steps(seed: int, violate: bool):
    """A run with a person approaching, a joint near its limit and the EE pushed at a wall."""
    rng = np.random.default_rng(seed)
    steps = make_steps(seed=seed)
    n = len(steps)
    t = steps["t"].to_numpy()
    d = 1.5 - 1.1 * np.exp(-(((t - 5.0) / 1.5) ** 2))  # closest approach 0.4 m at t = 5 s
    if violate:
        d = d - 0.1
    for k, cp in enumerate(("link_4", "link_6", "link_7")):
        steps[f"dist_true:{cp}"] = d + 0.1 * k
        meas = d + 0.1 * k + rng.normal(0.0, 0.01, n)
        meas[::7] = np.inf
        steps[f"dist_meas:{cp}"] = meas
    steps["truth:obstacle_link_7"] = d + 0.2
    steps["sigma:obstacle_link_7"] = np.where(d + 0.2 < 1.0, d + 0.2, np.inf)
    steps["active:obstacle_link_7"] = d + 0.2 < 0.45
    steps["sigma:joint_limit_2"] = 1.0 + 0.95 * np.sin(t)
    steps["active:joint_limit_2"] = steps["sigma:joint_limit_2"] > 1.8
    x = 0.3 + 0.22 * np.sin(0.5 * t)
    steps["ee_x"] = x
    steps["sigma:wall_x_max"] = 0.5 - x
    steps["ee_error_m"] = np.abs(np.sin(0.3 * t)) * 0.2
    steps["waypoint"] = (t > 5.0).astype(np.int32)
    return steps


METHODS = (("tpik", 1.0, False), ("hqp-daqp", 8.0, True))


def _write_run(run_dir: Path, seed: int = 0, methods: tuple = METHODS) -> Path:
    writer = ResultsWriter(run_dir, "synthetic", seed, 10.0, "x = 1\n")
    for name, slow, violate in methods:
        steps = _busy_steps(seed, violate)
        steps["solve_time_us"] = steps["solve_time_us"] * slow
        writer.add_method(name, compute_summary(steps, make_meta()), steps)
    writer.add_error("hqp-osqp", "NoSolutionFound | level 2")
    return run_dir


@pytest.fixture(scope="module")
def plotted_run(tmp_path_factory) -> tuple[Path, list[Path]]:
    """One run with two methods, plotted once (rendering is the slow part of these tests)."""
    run = _write_run(tmp_path_factory.mktemp("plots") / "run")
    return run, plot_run(run)


def _assert_png(path: Path, min_width: int = 400) -> None:
    assert path.is_file() and path.suffix == ".png"
    assert path.stat().st_size > MIN_PNG_BYTES, path
    img = imread(path)
    assert img.ndim == 3 and img.shape[1] >= min_width and img.shape[0] >= 200, (path, img.shape)


def test_plot_run_writes_the_paper_figures_and_the_comparison(plotted_run):
    run, paths = plotted_run
    names = {p.name for p in paths}
    for method in ("tpik", "hqp-daqp"):
        for kind in ("ee_error", "distances", "joints", "ee_walls"):
            assert f"{method}_{kind}.png" in names
    assert "comparison.png" in names
    assert all(p.parent == run / "plots" for p in paths)
    for p in paths:
        _assert_png(p)


def test_plot_run_without_walls_or_steps_skips_those_figures(tmp_path):
    run = _write_run(tmp_path / "run", methods=(("tpik", 1.0, False), ("mink", 30.0, True)))
    summary = load_summary(run)
    for m in summary["methods"].values():
        m["set_tasks"] = [t for t in m["set_tasks"] if t["group"] != "walls"]
    (run / "summary.json").write_text(json.dumps(summary))
    (run / "steps" / "mink.parquet").unlink()
    names = {p.name for p in plot_run(run)}
    assert not any(n.endswith("_ee_walls.png") for n in names)
    assert not any(n.startswith("mink_") for n in names)
    assert "comparison.png" in names


def test_wall_axis_is_recovered_from_the_data():
    steps = _busy_steps(0, False)
    assert wall_axis(steps, WALL_X_MAX) == (0, -1.0, pytest.approx(-0.5))
    steps["sigma:wall_x_max"] = steps["sigma:wall_x_max"] + 0.01 * np.sin(steps["t"])
    assert wall_axis(steps, WALL_X_MAX) is None


def test_plot_sweep_writes_comparison_and_distance_cdf(tmp_path):
    for i in range(3):
        _write_run(sweep_run_dir(tmp_path, i), seed=i, methods=(*METHODS, ("mink", 30.0, i % 2 == 0)))
    paths = plot_sweep(tmp_path)
    assert {p.name for p in paths} == {"sweep_comparison.png", "sweep_min_distance_cdf.png"}
    for p in paths:
        _assert_png(p)


def test_sweep_comparison_names_every_method_in_a_legend(tmp_path, monkeypatch):
    """Methods with close figures get one legend entry each, not notes written over each other."""
    import compare.analysis.plots as plots

    figures = {}
    real_save = plots.save_figure

    def keep(fig, path):
        figures[Path(path).name] = fig
        return real_save(fig, path)

    monkeypatch.setattr(plots, "save_figure", keep)
    for i in range(2):
        _write_run(sweep_run_dir(tmp_path, i), seed=i, methods=(*METHODS, ("mink", 30.0, True)))
    plot_sweep(tmp_path)
    per_method = figures["sweep_comparison.png"].axes[0]
    names = [text.get_text() for text in per_method.get_legend().get_texts()]
    assert names == [f"{m[0]} (n=2)" for m in (*METHODS, ("mink",))]
    assert not per_method.texts  # no note beside a point


def test_summary_table_wide_and_narrow(plotted_run):
    run, _ = plotted_run
    summary = load_summary(run)
    console = Console(width=250, record=True)
    console.print(summary_table(summary))
    text = console.export_text()
    for token in ("tpik", "hqp-daqp", "hqp-osqp", "failed: NoSolutionFound", "joint margin [rad]", "-0.050 (2×"):
        assert token in text
    narrow = Console(width=80, record=True)  # a terminal of 80 columns: one column per method
    narrow.print(summary_table(summary, narrow=True))
    lines = narrow.export_text().splitlines()
    assert max(len(line) for line in lines) <= 80
    assert any(line.split("│")[1].strip() == "solve median [µs]" for line in lines if line.count("│") > 2)
    assert "tpik" in lines[2] and "hqp-daqp" in lines[2]


def _purple_pixels(path: Path) -> int:
    img = imread(path)[..., :3]
    purple = np.array([148, 103, 189]) / 255.0  # matplotlib tab:purple
    return int(np.count_nonzero(np.all(np.abs(img - purple) < 0.06, axis=-1)))


def test_distance_plot_marks_readings_assumed_from_hidden_space(tmp_path):
    from compare.analysis.plots import plot_distances

    steps = _busy_steps(0, False)
    t = steps["t"].to_numpy()
    for cp in ("link_4", "link_6", "link_7"):
        steps[f"occluded:{cp}"] = False
    plain = plot_distances(steps, "tpik", ["link_4", "link_6", "link_7"], [], tmp_path / "plain.png")
    steps["occluded:link_6"] = (t > 4.0) & (t < 6.0)
    marked = plot_distances(steps, "tpik", ["link_4", "link_6", "link_7"], [], tmp_path / "marked.png")
    assert _purple_pixels(plain) == 0
    assert _purple_pixels(marked) > 50

"""Results directories: summary.json contract, atomic rewrites, steps tables, sweeps."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from compare.analysis import results as results_module
from compare.analysis.exceptions import DirectoryBusy, ResultsConflict
from compare.analysis.metrics import compute_summary
from compare.analysis.results import (
    ResultsWriter,
    collect_sweep,
    finished_methods,
    is_finished,
    load_steps,
    load_summary,
    merge_run_summary,
    sweep_run_dir,
    write_json_atomic,
    write_sweep_summary,
)
from tests.compare.analysis.test_metrics import REQUIRED_KEYS, make_meta, make_steps


def _method_result(
    violate: bool = False, slow: float = 1.0, obstacle_m: float | None = None
) -> tuple[dict, pd.DataFrame]:
    steps = make_steps()
    steps["solve_time_us"] = steps["solve_time_us"] * slow
    if violate:
        sigma = steps["sigma:joint_limit_2"].to_numpy().copy()
        sigma[100:105] = 1.95
        steps["sigma:joint_limit_2"] = sigma
    if obstacle_m is not None:
        truth = np.full(len(steps), np.inf)
        truth[200:300] = obstacle_m
        steps["truth:obstacle_link_7"] = truth
        steps["sigma:obstacle_link_7"] = truth
        steps["dist_true:link_7"] = truth
    return compute_summary(steps, make_meta()), steps


def _write_run(run_dir: Path, seed: int, methods: dict[str, dict], errors: dict[str, str] | None = None) -> None:
    writer = ResultsWriter(run_dir, "synthetic", seed, 10.0, "[scenario]\nname = 'synthetic'\n")
    for name, kwargs in methods.items():
        summary, steps = _method_result(**kwargs)
        writer.add_method(name, summary, steps)
    for name, message in (errors or {}).items():
        writer.add_error(name, message)


def test_writer_creates_directory_config_and_top_level_keys(tmp_path):
    out = tmp_path / "a" / "run"
    writer = ResultsWriter(out, "case1", 3, 70.0, "x = 1\n")
    assert (out / "config.toml").read_text() == "x = 1\n"
    summary = load_summary(out)
    assert set(summary) == {
        "scenario",
        "seed",
        "sim_time_s",
        "versions",
        "config_hash",
        "config_fingerprint",
        "methods",
    }
    assert summary["scenario"] == "case1" and summary["seed"] == 3 and summary["sim_time_s"] == 70.0
    assert summary["methods"] == {}
    assert "python" in summary["versions"]
    assert writer.summary == summary


def test_add_method_writes_parquet_and_exact_method_keys(tmp_path):
    summary, steps = _method_result(violate=True)
    writer = ResultsWriter(tmp_path, "synthetic", 0, 10.0, None)
    path = writer.add_method("hqp-daqp", summary, steps)
    assert path == tmp_path / "steps" / "hqp-daqp.parquet" and path.is_file()
    assert not (tmp_path / "config.toml").exists()
    stored = load_summary(tmp_path)["methods"]["hqp-daqp"]
    assert REQUIRED_KEYS <= set(stored)
    assert stored["joint_limits"]["violations"] == 1
    assert stored["steps_file"] == "steps/hqp-daqp.parquet"
    text = (tmp_path / "summary.json").read_text()
    assert "NaN" not in text and "Infinity" not in text
    back = load_steps(tmp_path, "hqp-daqp")
    pd.testing.assert_frame_equal(back, steps, check_dtype=False)


def test_add_error_keeps_methods_already_written(tmp_path):
    writer = ResultsWriter(tmp_path, "synthetic", 0, 10.0, None)
    summary, steps = _method_result()
    writer.add_method("tpik", summary, steps)
    writer.add_error("hqp-osqp", "NoSolutionFound: level 2")
    writer.add_method("mink", summary, steps)
    on_disk = load_summary(tmp_path)
    assert set(on_disk["methods"]) == {"tpik", "mink"}
    assert on_disk["errors"] == {"hqp-osqp": "NoSolutionFound: level 2"}
    assert not list(tmp_path.glob(".summary.json.*"))  # no temp file left behind


def test_a_crash_during_a_rewrite_leaves_the_previous_summary(tmp_path, monkeypatch):
    writer = ResultsWriter(tmp_path, "synthetic", 0, 10.0, None)
    summary, steps = _method_result()
    writer.add_method("tpik", summary, steps)

    def boom(*args, **kwargs):
        raise OSError("disk full")

    monkeypatch.setattr("compare.analysis.results.os.replace", boom)
    with pytest.raises(OSError, match="disk full"):
        writer.add_error("mink", "crash")
    assert set(load_summary(tmp_path)["methods"]) == {"tpik"}
    assert "errors" not in load_summary(tmp_path)
    assert not list(tmp_path.glob(".summary.json.*"))


def test_steps_fall_back_to_csv_when_parquet_fails(tmp_path, monkeypatch):
    def no_parquet(*args, **kwargs):
        raise ImportError("pyarrow missing")

    monkeypatch.setattr(results_module.pq, "write_table", no_parquet)
    summary, steps = _method_result()
    path = ResultsWriter(tmp_path, "synthetic", 0, 10.0, None).add_method("tpik", summary, steps)
    assert path.suffix == ".csv"
    back = load_steps(tmp_path, "tpik")
    assert math.isinf(back["sigma:obstacle_link_7"].iloc[0])
    assert back["status"].iloc[0] == "ok"


def test_steps_parquet_reads_back_as_the_same_table(tmp_path):
    """Column by column (no pandas metadata): every dtype, NaN and ±inf come back as written."""
    n = 5
    steps = pd.DataFrame(
        {
            "t": np.arange(n) * 0.01,
            "sigma:x": [0.1, np.nan, np.inf, -np.inf, 2.0],
            "deadline_miss": np.array([True, False, True, False, False]),
            "waypoint": np.arange(n, dtype=np.int32),
            "status": ["ok", "degraded", "ok", "failed", "ok"],
            "reason": [None, "blind", None, None, "stale"],
        }
    )
    path = tmp_path / "steps.parquet"
    results_module.write_steps_parquet(steps, path)
    back = pd.read_parquet(path)
    pd.testing.assert_frame_equal(back, steps, check_dtype=True)


def test_load_steps_names_available_methods(tmp_path):
    summary, steps = _method_result()
    ResultsWriter(tmp_path, "synthetic", 0, 10.0, None).add_method("tpik", summary, steps)
    with pytest.raises(FileNotFoundError, match="available: tpik"):
        load_steps(tmp_path, "mink")


def test_write_json_atomic_refuses_nan(tmp_path):
    with pytest.raises(ValueError):
        write_json_atomic(tmp_path / "x.json", {"a": float("nan")})
    assert not (tmp_path / "x.json").exists()


def test_is_finished_needs_every_requested_method(tmp_path):
    run = sweep_run_dir(tmp_path, 42)
    assert run == tmp_path / "runs" / "00042"
    assert not is_finished(run, ["tpik"])
    _write_run(run, 42, {"tpik": {}}, errors={"mink": "boom"})
    assert is_finished(run, ["tpik"])
    assert not is_finished(run, ["tpik", "mink"])
    assert not is_finished(run)  # an error is recorded
    (run / "summary.json").write_text("{ truncated")
    assert not is_finished(run, ["tpik"])


def _fake_sweep(root: Path) -> None:
    _write_run(sweep_run_dir(root, 0), 0, {"tpik": {}, "hqp-daqp": {"slow": 10.0, "obstacle_m": 0.5}})
    _write_run(
        sweep_run_dir(root, 1),
        1,
        {"tpik": {"violate": True, "obstacle_m": 0.3}, "hqp-daqp": {"slow": 10.0, "obstacle_m": 0.4}},
    )
    _write_run(sweep_run_dir(root, 2), 2, {"tpik": {"obstacle_m": 0.6}}, errors={"hqp-daqp": "NoSolutionFound"})


def test_collect_sweep_has_one_row_per_run_and_method(tmp_path):
    _fake_sweep(tmp_path)
    runs = collect_sweep(tmp_path)
    assert len(runs) == 6
    assert sorted(runs["run"].unique()) == ["00000", "00001", "00002"]
    for col in (
        "seed",
        "method",
        "error",
        "solve_median_us",
        "solve_p99_us",
        "joint_limits_safety_margin_min",
        "walls_physical_margin_min",
        "obstacles_violations",
        "min_obstacle_distance_m",
        "ee_error_final_m",
        "failures",
        "fallbacks",
    ):
        assert col in runs.columns, col
    tpik = runs[runs["method"] == "tpik"].set_index("seed")
    assert tpik.loc[1, "joint_limits_violations"] == 1
    assert tpik.loc[1, "min_obstacle_distance_m"] == pytest.approx(0.3)
    failed = runs[runs["error"].notna()]
    assert list(failed["method"]) == ["hqp-daqp"] and list(failed["seed"]) == [2]


def test_sweep_summary_aggregates_per_method(tmp_path):
    _fake_sweep(tmp_path)
    summary = write_sweep_summary(tmp_path)
    on_disk = json.loads((tmp_path / "sweep_summary.json").read_text())
    assert on_disk == summary
    assert (tmp_path / "sweep_runs.csv").is_file()
    assert summary["runs"] == 3
    tpik, hqp = summary["methods"]["tpik"], summary["methods"]["hqp-daqp"]
    assert tpik["runs"] == 3 and tpik["errors"] == 0
    assert hqp["runs"] == 2 and hqp["errors"] == 1
    assert tpik["share_runs_limit_or_wall_violation"]["rate"] == pytest.approx(1 / 3)
    assert tpik["share_runs_obstacle_violation"]["rate"] == pytest.approx(1 / 3)  # 0.3 m < 0.35 m in run 1
    assert hqp["share_runs_limit_or_wall_violation"]["rate"] == 0.0
    assert hqp["share_runs_obstacle_violation"]["rate"] == 0.0
    assert hqp["min_obstacle_distance_m"] == pytest.approx(0.4)
    assert tpik["worst_safety_margin"]["joint_limits"] == pytest.approx(-0.05)
    assert tpik["worst_safety_margin"]["obstacles"] == pytest.approx(-0.05)
    assert hqp["solve_time_us"]["median_of_medians"] > 5 * tpik["solve_time_us"]["median_of_medians"]
    json.dumps(summary, allow_nan=False)


def test_empty_sweep_is_not_an_error(tmp_path):
    assert collect_sweep(tmp_path).empty
    summary = write_sweep_summary(tmp_path)
    assert summary["runs"] == 0 and summary["methods"] == {}


# ------------------------------------------------------------------ results directories are safe

HASH_A, HASH_B = "a" * 64, "b" * 64
FP_A = {"scenario.name": "synthetic", "scenario.duration_s": 10.0, "scenario.seed": 0}
FP_B = {**FP_A, "scenario.duration_s": 12.0}


def _writer(out: Path, methods: list[str], config_hash: str | None = HASH_A, **kwargs) -> ResultsWriter:
    fingerprint = FP_A if config_hash == HASH_A else FP_B
    return ResultsWriter(
        out,
        "synthetic",
        0,
        10.0,
        "x = 1\n",
        config_hash=config_hash,
        config_fingerprint=fingerprint,
        methods=methods,
        **kwargs,
    )


def _add(writer: ResultsWriter, name: str, **kwargs) -> Path:
    summary, steps = _method_result(**kwargs)
    return writer.add_method(name, summary, steps)


def test_a_second_run_with_the_same_config_adds_its_method_and_touches_nothing_else(tmp_path):
    with _writer(tmp_path, ["tpik"]) as w:
        tpik_table = _add(w, "tpik")
    before = (tpik_table.read_bytes(), tpik_table.stat().st_mtime_ns, load_summary(tmp_path)["methods"]["tpik"])
    with _writer(tmp_path, ["hqp-daqp"]) as w:
        _add(w, "hqp-daqp", slow=10.0)
    summary = load_summary(tmp_path)
    assert set(summary["methods"]) == {"tpik", "hqp-daqp"}
    assert (tpik_table.read_bytes(), tpik_table.stat().st_mtime_ns, summary["methods"]["tpik"]) == before
    assert (
        summary["methods"]["hqp-daqp"]["solve_time_us"]["median"]
        > summary["methods"]["tpik"]["solve_time_us"]["median"]
    )


def test_a_method_with_finished_results_is_refused_without_overwrite(tmp_path):
    with _writer(tmp_path, ["tpik"]) as w:
        _add(w, "tpik")
    with pytest.raises(ResultsConflict, match=r"already holds finished results of tpik; use --overwrite"):
        _writer(tmp_path, ["hqp-daqp", "tpik"])
    assert set(load_summary(tmp_path)["methods"]) == {"tpik"}


def test_another_config_is_refused_naming_the_key_that_differs(tmp_path):
    with _writer(tmp_path, ["tpik"]) as w:
        _add(w, "tpik")
    with pytest.raises(ResultsConflict) as err:
        _writer(tmp_path, ["mink"], config_hash=HASH_B)
    message = str(err.value)
    assert "another configuration (scenario.duration_s 10.0 → 12.0)" in message and "\n" not in message


def test_results_without_a_config_hash_are_refused(tmp_path):
    with ResultsWriter(tmp_path, "synthetic", 0, 10.0, None) as w:  # an older version's directory
        _add(w, "tpik")
    with pytest.raises(ResultsConflict, match="no config hash"):
        _writer(tmp_path, ["mink"])


def test_results_of_another_project_version_are_refused(tmp_path, monkeypatch):
    with _writer(tmp_path, ["tpik"]) as w:
        _add(w, "tpik")
    monkeypatch.setattr("compare.analysis.results.run_versions", lambda: {"project": "99.0", "python": "3.11"})
    with pytest.raises(ResultsConflict, match=r"tpik-compare .* this is 99\.0"):
        _writer(tmp_path, ["mink"])


def test_overwrite_replaces_every_method_on_purpose(tmp_path):
    with _writer(tmp_path, ["tpik", "mink"]) as w:
        _add(w, "tpik")
        _add(w, "mink")
    (tmp_path / "plots").mkdir()
    (tmp_path / "plots" / "old.png").write_bytes(b"png")
    with _writer(tmp_path, ["tpik"], config_hash=HASH_B, overwrite=True) as w:
        _add(w, "tpik", slow=3.0)
    summary = load_summary(tmp_path)
    assert set(summary["methods"]) == {"tpik"} and summary["config_hash"] == HASH_B
    assert sorted(p.name for p in (tmp_path / "steps").iterdir()) == ["tpik.parquet"]
    assert not (tmp_path / "plots").exists()


def test_a_sweep_directory_is_refused_even_with_overwrite(tmp_path):
    _write_run(sweep_run_dir(tmp_path, 0), 0, {"tpik": {}})
    for overwrite in (False, True):
        with pytest.raises(ResultsConflict, match="is a sweep directory"):
            _writer(tmp_path, ["tpik"], overwrite=overwrite)
    assert is_finished(sweep_run_dir(tmp_path, 0), ["tpik"])


def test_an_unreadable_summary_is_refused_not_replaced(tmp_path):
    (tmp_path / "summary.json").write_text('{"scenario": "x", "meth')
    with pytest.raises(ResultsConflict, match="unreadable"):
        _writer(tmp_path, ["tpik"])
    assert (tmp_path / "summary.json").read_text() == '{"scenario": "x", "meth'


def test_a_method_with_a_truncated_table_is_not_finished_and_is_run_again(tmp_path):
    with _writer(tmp_path, ["tpik", "mink"]) as w:
        _add(w, "tpik")
        table = _add(w, "mink")
    data = table.read_bytes()
    table.write_bytes(data[: len(data) // 2])  # e.g. written by an older, non-atomic version
    assert finished_methods(tmp_path) == {"tpik"}
    assert not is_finished(tmp_path, ["mink"]) and is_finished(tmp_path, ["tpik"])
    with _writer(tmp_path, ["mink"]) as w:  # no --overwrite needed: it was not a finished result
        _add(w, "mink")
    assert finished_methods(tmp_path) == {"tpik", "mink"}


def test_a_table_with_fewer_rows_than_recorded_is_not_finished(tmp_path):
    with _writer(tmp_path, ["tpik"]) as w:
        table = _add(w, "tpik")
    pd.read_parquet(table).iloc[:10].to_parquet(table, index=False)
    assert finished_methods(tmp_path) == set()


def test_a_second_writer_of_the_same_directory_is_refused_while_the_first_is_open(tmp_path):
    first = _writer(tmp_path, ["tpik"])
    with pytest.raises(DirectoryBusy, match="being written by another tpik-compare process"):
        _writer(tmp_path, ["mink"])
    first.close()
    with _writer(tmp_path, ["mink"]) as w:
        _add(w, "mink")


def test_a_crash_between_table_and_summary_leaves_a_run_that_is_completed_later(tmp_path, monkeypatch):
    import compare.analysis.atomic_files as atomic

    with _writer(tmp_path, ["tpik", "mink"]) as w:
        _add(w, "tpik")

        def crash(tmp: Path, final: Path) -> None:
            if final.name == "summary.json":
                raise KeyboardInterrupt  # killed after mink's table, before the summary naming it

        monkeypatch.setattr(atomic, "before_replace", crash)
        with pytest.raises(KeyboardInterrupt):
            _add(w, "mink")
        monkeypatch.setattr(atomic, "before_replace", None)
    assert set(load_summary(tmp_path)["methods"]) == {"tpik"}
    assert not list(tmp_path.glob(".summary.json.*"))
    with _writer(tmp_path, ["mink"]) as w:  # the resume runs the missing method only
        _add(w, "mink")
    assert finished_methods(tmp_path) == {"tpik", "mink"}


def test_merge_run_summary_keeps_the_methods_already_there(tmp_path):
    _write_run(tmp_path, 0, {"tpik": {}}, errors={"mink": "boom"})
    incoming = {**load_summary(tmp_path), "methods": {"mink": {"failures": 0}}}
    incoming.pop("errors")
    merged = merge_run_summary(tmp_path, incoming)
    assert set(merged["methods"]) == {"tpik", "mink"} and "errors" not in merged
    assert load_summary(tmp_path) == merged


def test_versions_are_read_once_and_each_caller_gets_its_own_dict():
    from importlib import metadata

    from compare.versions import versions

    first = versions()
    assert first["project"] == metadata.version("tpik-compare") and first["numpy"] == metadata.version("numpy")
    first["numpy"] = "edited"
    assert versions()["numpy"] == metadata.version("numpy")

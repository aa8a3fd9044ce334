"""What a replay needs is in the results directory; old results, unknown methods and seeds are one line."""

from __future__ import annotations

import json
import shutil
import tomllib
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from compare.analysis.results import REPLAY_FILE, REPLAY_FORMAT, merge_run_summary
from compare.cli import app
from compare.config import dump_config, load_config, parse_config
from compare.replay.exceptions import ReplayError
from compare.replay.run_data import load_run, resolve_run_dir
from compare.scenarios.random_scenario import realize

CONFIGS = Path(__file__).resolve().parents[3] / "configs"


def _one_error_line(result) -> str:
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert result.exit_code == 2, result.output
    assert len(lines) == 1 and lines[0].startswith("error: "), result.output
    return lines[0]


def test_a_run_records_its_concrete_scenario_and_a_format_marker(case2_run):
    summary = json.loads((case2_run / "summary.json").read_text())
    assert summary["replay"] == {"format": REPLAY_FORMAT, "scenario_file": REPLAY_FILE}
    for key in ("scenario", "seed", "sim_time_s", "versions", "config_hash", "config_fingerprint", "methods"):
        assert key in summary  # the record is added beside every existing key
    recorded = parse_config(tomllib.loads((case2_run / REPLAY_FILE).read_text()))
    assert recorded.scenario.time_scale == 0.1 and recorded.scenario.sensing == "depth"


def test_a_random_scenario_round_trips_through_its_dump_with_the_draw_resolved():
    config, _ = load_config(CONFIGS / "random.toml", {"scenario.seed": 11})
    concrete = realize(config, draw=2)
    back = parse_config(tomllib.loads(dump_config(concrete)))
    assert back == concrete
    assert back.person.keyframes == concrete.person.keyframes and back.scenario.start_q == concrete.scenario.start_q


def test_load_run_reads_every_method_and_the_window(case2_run):
    run = load_run(case2_run, t_from=1.0, t_to=2.5)
    assert [m.name for m in run.methods] == ["tpik", "mink"]
    assert (run.t_from, run.t_to) == (1.0, 2.5)
    assert run.control_points == ("link_4", "link_6", "link_7")
    tpik = run.methods[0]
    assert tpik.q.shape == (len(tpik.t), 7)
    np.testing.assert_array_equal(tpik.rows_at([0.0, 0.015, 99.0]), [0, 1, len(tpik.t) - 1])
    assert load_run(case2_run, t_to=1e9).t_to == pytest.approx(4.0)  # clipped to the run


def test_old_results_are_refused_with_one_line(case2_run, tmp_path):
    old = tmp_path / "old"
    shutil.copytree(case2_run, old)
    summary = json.loads((old / "summary.json").read_text())
    del summary["replay"]
    (old / "summary.json").write_text(json.dumps(summary))
    (old / REPLAY_FILE).unlink()
    result = CliRunner().invoke(app, ["replay", str(old), "--video", str(tmp_path / "v.mp4")])
    assert "no replay record" in _one_error_line(result)
    assert not (tmp_path / "v.mp4").exists()


def test_a_newer_replay_format_is_refused(case2_run, tmp_path):
    newer = tmp_path / "newer"
    shutil.copytree(case2_run, newer)
    summary = json.loads((newer / "summary.json").read_text())
    summary["replay"]["format"] = REPLAY_FORMAT + 1
    (newer / "summary.json").write_text(json.dumps(summary))
    with pytest.raises(ReplayError, match="newer"):
        load_run(newer)


@pytest.mark.parametrize(
    ("args", "words"),
    [
        (["-m", "hqp-osqp"], "no results of method hqp-osqp"),
        (["--from", "5"], "empty window"),
        (["--seed", "3"], "a run of seed 0, not 3"),
    ],
)
def test_user_mistakes_are_one_line_and_exit_2(case2_run, tmp_path, args, words):
    result = CliRunner().invoke(app, ["replay", str(case2_run), "--still", str(tmp_path / "s.png"), *args])
    assert words in _one_error_line(result)


def test_a_missing_directory_an_output_of_the_wrong_kind_or_none_is_one_line(case2_run, tmp_path):
    runner = CliRunner()
    assert "no such" in _one_error_line(runner.invoke(app, ["replay", str(tmp_path / "x"), "--rerun", "a.rrd"]))
    assert ".mp4" in _one_error_line(runner.invoke(app, ["replay", str(case2_run), "--video", "a.avi"]))
    assert ".rrd" in _one_error_line(runner.invoke(app, ["replay", str(case2_run), "--rerun", "a.mp4"]))
    assert "nothing to write" in _one_error_line(runner.invoke(app, ["replay", str(case2_run)]))
    assert "WIDTHxHEIGHT" in _one_error_line(
        runner.invoke(app, ["replay", str(case2_run), "--still", "a.png", "--size", "big"])
    )


def _fake_sweep(run_dir: Path, out: Path, seeds: list[int]) -> Path:
    for i, seed in enumerate(seeds):
        target = out / "runs" / f"{i:05d}"
        shutil.copytree(run_dir, target)
        summary = json.loads((target / "summary.json").read_text())
        summary["seed"] = seed
        (target / "summary.json").write_text(json.dumps(summary))
    return out


def test_a_sweep_needs_a_seed_it_holds(case2_run, tmp_path):
    sweep = _fake_sweep(case2_run, tmp_path / "sweep", [40, 41])
    assert resolve_run_dir(sweep, 41) == sweep / "runs" / "00001"
    runner = CliRunner()
    no_seed = _one_error_line(runner.invoke(app, ["replay", str(sweep), "--still", str(tmp_path / "s.png")]))
    assert "give --seed" in no_seed and "seeds 40–41" in no_seed
    absent = runner.invoke(app, ["replay", str(sweep), "--seed", "7", "--still", str(tmp_path / "s.png")])
    assert "no run of seed 7" in _one_error_line(absent)


def test_a_merged_summary_takes_the_replay_record_an_older_one_lacks(tmp_path):
    (tmp_path / "summary.json").write_text(json.dumps({"scenario": "s", "methods": {"a": {}}}))
    merged = merge_run_summary(tmp_path, {"scenario": "s", "replay": {"format": 1}, "methods": {"b": {}}})
    assert merged["replay"] == {"format": 1} and set(merged["methods"]) == {"a", "b"}


@pytest.mark.slow
@pytest.mark.rendering
def test_a_sweep_s_run_is_replayed_by_its_seed(tmp_path):
    from compare.campaign.sweep import run_sweep

    config, text = load_config(CONFIGS / "random.toml", {"scenario.duration_s": 0.5, "scenario.seed": 500})
    sweep = tmp_path / "sweep"
    run_sweep(config, text, sweep, n=2, workers=1, methods=["tpik"], progress=False, report=False)
    run = load_run(sweep, seed=501)
    assert run.run_dir == sweep / "runs" / "00001"
    drawn = realize(config.model_copy(update={"scenario": config.scenario.model_copy(update={"seed": 501})}))
    assert run.config.person.keyframes == drawn.person.keyframes  # the seed's own draw, not seed 500's
    out, rrd = tmp_path / "seed501.mp4", tmp_path / "seed501.rrd"
    args = ["replay", str(sweep), "--seed", "501", "--video", str(out), "--size", "320x192", "--fps", "10"]
    result = CliRunner().invoke(app, [*args, "--rerun", str(rrd), "-q"])
    assert result.exit_code == 0, result.output
    assert "runs/00001" in result.output and out.stat().st_size > 0
    from rerun.chunk import RrdReader

    paths = {chunk.entity_path for chunk in RrdReader(rrd).stream().collect().stream()}
    assert "/world/tpik/control_points" in paths and "/plots/solve_time_us/tpik" in paths
    assert not any("depth" in p or "cameras" in p for p in paths)  # geometric sensing: no camera


def test_the_replay_package_reads_results_without_importing_what_runs_a_scenario():
    import subprocess
    import sys

    code = (
        "import sys, compare.replay.recording, compare.replay.video, compare.replay.run_data; "
        "print(' '.join(m for m in sys.modules if m.startswith(('compare.campaign', 'compare.run', "
        "'compare.methods', 'compare.loop.closed_loop', 'compare.loop.simulation'))))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == ""

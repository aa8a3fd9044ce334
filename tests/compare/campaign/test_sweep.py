"""Sweeps: N runs on a process pool produce N results and a summary; a re-run resumes only the same sweep."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from compare.analysis.atomic_files import FAULT_ENV
from compare.analysis.exceptions import DirectoryBusy, ResultsConflict
from compare.analysis.results import (
    TIMING_COLUMNS,
    DirectoryLock,
    deterministic_view,
    is_finished,
    load_steps,
    load_summary,
    sweep_run_dir,
)
from compare.campaign.manifest import make_manifest, run_config_hash
from compare.campaign.sweep import run_sweep, seeded_config
from compare.cli import app
from compare.config import load_config
from compare.config_hash import config_hash
from compare.scenarios.random_scenario import realize

ROOT = Path(__file__).resolve().parents[3]
CONFIGS = ROOT / "configs"


@pytest.mark.slow
def test_sweep_runs_four_seeds_then_skips_them(tmp_path):
    out = tmp_path / "sweep"
    args = [
        "sweep",
        str(CONFIGS / "random.toml"),
        "--n",
        "4",
        "--workers",
        "2",
        "--out",
        str(out),
        "--duration",
        "3",
        "-m",
        "tpik",
        "-m",
        "hqp-daqp",
    ]
    first = CliRunner().invoke(app, args)
    assert first.exit_code == 0, first.output
    runs = sorted((out / "runs").iterdir())
    assert len(runs) == 4
    seeds = [json.loads((r / "summary.json").read_text())["seed"] for r in runs]
    assert seeds == [0, 1, 2, 3]
    summary = json.loads((out / "sweep_summary.json").read_text())
    assert summary["runs"] == 4 and set(summary["methods"]) == {"tpik", "hqp-daqp"}
    plant = {"sensing": "geometric", "simulation": "dynamic", "drive": "decoupled", "drive_bandwidth_rad_s": 100.0}
    assert summary["campaign"]["plant"] == plant
    # Throughput: 4 runs x 2 methods x 3 s simulated, per CPU second of the sweep and its workers.
    campaign = summary["campaign"]
    assert campaign["cpu_time_s"] > 0.0
    assert campaign["sim_s_per_cpu_s"] == pytest.approx(4 * 2 * 3.0 / campaign["cpu_time_s"])
    assert 0.0 <= campaign["cpu_system_s"] < campaign["cpu_time_s"]  # the kernel's part of it
    assert campaign["steal_time_s"] is None or 0.0 <= campaign["steal_time_s"] <= 2 * campaign["wall_time_s"]
    for name, m in summary["methods"].items():  # no solver time limit in simulation without [loop] realtime
        worst = [json.loads((r / "summary.json").read_text())["methods"][name]["solve_worst_us"]["us"] for r in runs]
        assert worst == [None] * 4 and m["solve_time_us"]["max_on_limit_clock"] is None
        assert m["solve_time_us"]["max"] > 0.0
    report = (out / "sweep_report.md").read_text()
    assert "simulated s per CPU s" in report and "worst step after warm-up" in report
    kernel = f"({campaign['cpu_system_s'] / campaign['cpu_time_s']:.0%} of it in the kernel)"
    assert kernel in report
    assert "- plant: dynamic simulation, decoupled joint drive (λ = 100 rad/s), geometric sensing" in report
    stamps = [(r / "summary.json").stat().st_mtime_ns for r in runs]

    again = CliRunner().invoke(app, args)
    assert again.exit_code == 0, again.output
    assert [(r / "summary.json").stat().st_mtime_ns for r in runs] == stamps  # nothing redone


def test_random_scenarios_are_reproducible_and_differ_by_seed():
    config, _ = load_config(CONFIGS / "random.toml")
    a = realize(config)
    b = realize(config)
    c = realize(config.model_copy(update={"scenario": config.scenario.model_copy(update={"seed": 1})}))
    assert a == b
    assert a.waypoints.positions != c.waypoints.positions
    assert a.scenario.start_q != c.scenario.start_q
    lo, hi = config.random.workspace_lower, config.random.workspace_upper
    for p in a.waypoints.positions:
        assert all(lo[k] <= p[k] <= hi[k] for k in range(3))
    assert len(a.person.keyframes) > 1


# ------------------------------------------------------------------ resume checks what it resumes

SHORT = ["--duration", "0.5", "--workers", "1"]


def _sweep(out: Path, *extra: str):
    return CliRunner().invoke(app, ["sweep", str(CONFIGS / "random.toml"), "--out", str(out), *SHORT, *extra])


def _steps_bytes(out: Path) -> dict[str, bytes]:
    return {str(p.relative_to(out)): p.read_bytes() for p in sorted((out / "runs").rglob("*.parquet"))}


def _direct(out: Path, n: int, methods: list[str], duration: float = 0.5, **kwargs) -> dict:
    """``run_sweep`` as the CLI calls it, without plots and report (the slow part of a short sweep)."""
    config, text = load_config(CONFIGS / "random.toml", {"scenario.duration_s": duration})
    return run_sweep(config, text, out, n=n, workers=1, methods=methods, progress=False, report=False, **kwargs)


def test_a_sweep_of_one_method_then_more_runs_of_another_keeps_every_finished_result(tmp_path):
    """The second command pair of a resumed sweep: the resume adds hqp-daqp everywhere, tpik stays as it was."""
    out = tmp_path / "S"
    first = _sweep(out, "--n", "2", "-m", "tpik")
    assert first.exit_code == 0, first.output
    tpik = _steps_bytes(out)
    tpik_summaries = [json.loads((out / "runs" / f"0000{i}" / "summary.json").read_text()) for i in range(2)]
    second = _sweep(out, "--n", "3", "-m", "hqp-daqp")
    assert second.exit_code == 0, second.output
    after = _steps_bytes(out)
    assert {k: after[k] for k in tpik} == tpik  # the finished TPIK tables were not rewritten
    assert sorted(after) == sorted([*tpik, *(f"runs/0000{i}/steps/hqp-daqp.parquet" for i in range(3))])
    for i in range(2):
        summary = json.loads((out / "runs" / f"0000{i}" / "summary.json").read_text())
        assert summary["methods"]["tpik"] == tpik_summaries[i]["methods"]["tpik"]
        assert set(summary["methods"]) == {"tpik", "hqp-daqp"}
    sweep = json.loads((out / "sweep_summary.json").read_text())
    assert {m: v["runs"] for m, v in sweep["methods"].items()} == {"tpik": 2, "hqp-daqp": 3}
    assert sweep["campaign"]["pairs_executed"] == 3 and sweep["runs"] == 3
    manifest = json.loads((out / "sweep_manifest.json").read_text())
    assert manifest["methods"] == ["tpik", "hqp-daqp"] and manifest["runs"] == 3
    third = _direct(out, 3, ["tpik", "hqp-daqp"])  # only run 2's tpik is missing
    assert third["campaign"]["pairs_executed"] == 1


@pytest.fixture(scope="module")
def one_run_sweep(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("sweep") / "S"
    _direct(out, 1, ["tpik"])
    return out


@pytest.mark.parametrize(
    ("extra", "fragment"),
    [
        (["--duration", "0.6"], "another config (scenario.duration_s 0.5 → 0.6)"),
        (["--simulation", "kinematic"], 'another plant (scenario.simulation "dynamic" → "kinematic")'),
        (["--sensing", "depth"], 'another plant (scenario.sensing "geometric" → "depth")'),
    ],
)
def test_a_resume_with_another_config_or_plant_is_one_line_and_exit_2(one_run_sweep, extra, fragment):
    before = _steps_bytes(one_run_sweep)
    result = _sweep(one_run_sweep, "--n", "1", "-m", "tpik", *extra)
    assert result.exit_code == 2
    assert result.output.count("\n") == 1 and fragment in result.output
    assert "use another --out for a new sweep, or --overwrite to discard this one" in result.output
    assert _steps_bytes(one_run_sweep) == before


def test_a_resume_with_another_first_seed_is_refused(one_run_sweep, tmp_path):
    config = tmp_path / "seed5.toml"
    config.write_text((CONFIGS / "random.toml").read_text().replace("seed = 0", "seed = 5"))
    args = ["sweep", str(config), "--out", str(one_run_sweep), "--n", "1", "-m", "tpik", *SHORT]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 2 and "(scenario.seed 0 → 5)" in result.output


def test_a_resume_with_other_method_settings_is_refused(one_run_sweep, tmp_path):
    config = tmp_path / "settings.toml"
    config.write_text(
        (CONFIGS / "random.toml").read_text() + '\n[methods.settings.tpik]\nselection = "fewest_active"\n'
    )
    args = ["sweep", str(config), "--out", str(one_run_sweep), "--n", "1", "-m", "tpik", *SHORT]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 2 and "ran tpik with other settings ({} → " in result.output


def test_a_resume_with_another_project_version_is_refused(one_run_sweep, monkeypatch):
    monkeypatch.setattr("compare.campaign.manifest.project_version", lambda: "99.0")
    result = _sweep(one_run_sweep, "--n", "1", "-m", "tpik")
    assert (
        result.exit_code == 2 and "was started with tpik-compare" in result.output and "this is 99.0" in result.output
    )


def test_a_sweep_without_a_manifest_or_into_a_run_directory_is_refused(tmp_path):
    old = tmp_path / "old"
    (old / "runs" / "00000").mkdir(parents=True)  # an older version's sweep
    result = _sweep(old, "--n", "1", "-m", "tpik")
    assert result.exit_code == 2 and "holds a sweep without sweep_manifest.json (older version)" in result.output
    run = tmp_path / "run"
    run.mkdir()
    (run / "summary.json").write_text('{"methods": {}}')
    for extra in ([], ["--overwrite"]):
        result = _sweep(run, "--n", "1", "-m", "tpik", *extra)
        assert result.exit_code == 2 and "holds a single run, not a sweep" in result.output
    assert (run / "summary.json").read_text() == '{"methods": {}}'


def test_overwrite_discards_the_sweep_and_starts_again(tmp_path):
    out = tmp_path / "S"
    _direct(out, 2, ["tpik"])
    summary = _direct(out, 1, ["tpik"], duration=0.3, overwrite=True)
    assert summary["campaign"]["pairs_executed"] == 1
    assert sorted(p.name for p in (out / "runs").iterdir()) == ["00000"]
    assert json.loads((out / "sweep_manifest.json").read_text())["config_fingerprint"]["scenario.duration_s"] == 0.3


def test_an_incomplete_pair_is_run_again_and_an_unreadable_run_redone_whole(tmp_path):
    out = tmp_path / "S"
    _direct(out, 2, ["tpik", "hqp-daqp"])
    table = out / "runs" / "00000" / "steps" / "hqp-daqp.parquet"
    table.write_bytes(table.read_bytes()[:100])  # truncated (an older, non-atomic writer)
    (out / "runs" / "00001" / "summary.json").write_text('{"methods": {"tpik"')
    kept = (out / "runs" / "00000" / "steps" / "tpik.parquet").read_bytes()
    summary = _direct(out, 2, ["tpik", "hqp-daqp"])
    assert summary["campaign"]["pairs_executed"] == 3  # run 0's hqp-daqp, run 1 whole
    assert (out / "runs" / "00000" / "steps" / "tpik.parquet").read_bytes() == kept
    for i in range(2):
        assert is_finished(out / "runs" / f"0000{i}", ["tpik", "hqp-daqp"])


def test_a_run_of_another_config_inside_the_sweep_is_refused(tmp_path):
    out = tmp_path / "S"
    _direct(out, 1, ["tpik"])
    path = out / "runs" / "00000" / "summary.json"
    summary = json.loads(path.read_text())
    summary["config_hash"] = "0" * 64
    path.write_text(json.dumps(summary))
    with pytest.raises(ResultsConflict, match="holds a run of another configuration than this sweep's"):
        _direct(out, 1, ["hqp-daqp"])


def test_a_second_sweep_into_a_directory_being_written_is_refused(tmp_path):
    out = tmp_path / "S"
    out.mkdir()
    busy = DirectoryLock(out)  # another process's sweep
    try:
        with pytest.raises(DirectoryBusy, match="being written by another tpik-compare process"):
            _direct(out, 1, ["tpik"])
    finally:
        busy.release()


def test_a_run_s_config_hash_is_the_sweep_fingerprint_with_its_seed():
    config, _ = load_config(CONFIGS / "random.toml")
    manifest = make_manifest(config, 5, ["tpik"])
    for i in (0, 3):
        seeded = seeded_config(config, config.scenario.seed + i, ["hqp-daqp"])
        assert run_config_hash(manifest, i) == config_hash(seeded)
    assert run_config_hash(manifest, 0) != run_config_hash(manifest, 1)


def test_sweep_help_says_how_a_resume_is_checked():
    result = CliRunner().invoke(app, ["sweep", "--help"], terminal_width=200)
    text = " ".join(result.output.split())
    assert "resumes it" in text and "refused (exit 2) unless --overwrite" in text


def _sweep_command(out: Path) -> list[str]:
    cmd = [sys.executable, "-m", "compare.cli", "sweep", str(CONFIGS / "random.toml"), "--out", str(out)]
    return cmd + ["--n", "3", "-m", "tpik", "-m", "hqp-daqp", *SHORT]


def _killed_sweep(
    out: Path, env: dict[str, str], nth: int | None = None, delay: float | None = None
) -> tuple[int, str]:
    """One ``tpik-compare sweep`` process, killed mid-write (the fault hook, at the ``nth`` atomic
    write of a process) or after ``delay`` seconds."""
    if nth is not None:
        run_env = {**env, FAULT_ENV: f"*@{nth}"}  # SIGKILL at the nth atomic write of a process
        done = subprocess.run(
            _sweep_command(out), env=run_env, capture_output=True, text=True, timeout=300, start_new_session=True
        )
        return done.returncode, f"write {nth}"
    proc = subprocess.Popen(
        _sweep_command(out), env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, start_new_session=True
    )
    try:
        proc.wait(timeout=delay)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)  # the sweep and its worker process
        proc.wait(timeout=60)
    return proc.returncode, f"{delay:.1f} s"


@pytest.mark.slow
@pytest.mark.timeout(900)
def test_a_sweep_killed_at_random_points_and_resumed_ends_with_the_results_of_an_uninterrupted_one(tmp_path):
    """Killed by timer while the whole sweep lies ahead (started again with a shorter timer if the
    sweep outran it), then at the resumed process's first write (always lands: work remains), then
    at random points (writes or times) until it finishes."""
    env = {**os.environ, "PYTHONPATH": str(ROOT), "MUJOCO_GL": "egl"}
    env.pop(FAULT_ENV, None)
    reference = tmp_path / "reference"
    uninterrupted = subprocess.run(_sweep_command(reference), env=env, capture_output=True, text=True, timeout=300)
    assert uninterrupted.returncode == 0, uninterrupted.stderr
    start = time.perf_counter()  # timed again with the kernels compiled and cached, as the killed runs find them
    again = subprocess.run(_sweep_command(tmp_path / "again"), env=env, capture_output=True, text=True, timeout=300)
    took = time.perf_counter() - start  # this machine's time for the whole sweep: the timer's scale
    assert again.returncode == 0, again.stderr
    out = tmp_path / "killed"
    rng = np.random.default_rng(22)
    delay = float(rng.uniform(0.4, 0.7)) * took
    for _ in range(4):  # a loaded machine can make the reference slower than this sweep: start again, sooner
        code, where = _killed_sweep(out, env, delay=delay)
        if code != 0:
            break
        shutil.rmtree(out)
        delay /= 2
    assert code == -signal.SIGKILL, code
    kills = [where]
    attempts = [{"nth": 1}]
    attempts += [
        {"nth": int(rng.integers(1, 12))} if rng.random() < 0.5 else {"delay": float(rng.uniform(0.2, 0.8)) * took}
        for _ in range(3)
    ]
    for attempt in attempts:
        code, where = _killed_sweep(out, env, **attempt)
        if code == 0:
            break
        assert code == -signal.SIGKILL, code
        kills.append(where)
    assert len(kills) >= 2 and kills[1] == "write 1", kills
    final = subprocess.run(_sweep_command(out), env=env, capture_output=True, text=True, timeout=300)
    assert final.returncode == 0, final.stderr
    for i in range(3):
        ref_dir, run_dir = sweep_run_dir(reference, i), sweep_run_dir(out, i)
        assert deterministic_view(load_summary(run_dir)) == deterministic_view(load_summary(ref_dir)), (i, kills)
        for method in ("tpik", "hqp-daqp"):
            a, b = load_steps(run_dir, method), load_steps(ref_dir, method)
            timing = list(TIMING_COLUMNS)
            pd.testing.assert_frame_equal(a.drop(columns=timing), b.drop(columns=timing))
    assert not [p for p in out.rglob(".*.tmp")]  # the killed writes' temporaries were cleaned up
    sweep = json.loads((out / "sweep_summary.json").read_text())
    assert {m: v["runs"] for m, v in sweep["methods"].items()} == {"tpik": 3, "hqp-daqp": 3}


def test_machine_steal_is_the_eighth_value_of_the_cpu_line(tmp_path):
    from compare.campaign.sweep import machine_steal_s

    stat = tmp_path / "stat"
    stat.write_text("cpu  81401 164557 21012 42581 653 0 303 419 0 0\ncpu0 1 2 3 4 5 6 7 8 0 0\n")
    assert machine_steal_s(stat) == pytest.approx(419 / os.sysconf("SC_CLK_TCK"))
    stat.write_text("intr 12 34\n")
    assert machine_steal_s(stat) is None
    stat.write_text("cpu  1 2 3 4 5 6 7 x 0 0\n")  # a malformed field: no number, not a traceback
    assert machine_steal_s(stat) is None
    assert machine_steal_s(tmp_path / "missing") is None


@pytest.mark.parametrize(("flag", "progress"), [((), True), (("-q",), False), (("--quiet",), False)])
def test_sweep_quiet_turns_the_progress_bar_off(tmp_path, monkeypatch, flag, progress):
    import compare.campaign.sweep as sweep_module

    seen: dict[str, object] = {}

    def fake_run_sweep(*args: object, **kwargs: object) -> dict[str, object]:
        seen.update(kwargs)
        return {"runs": 1}

    monkeypatch.setattr(sweep_module, "run_sweep", fake_run_sweep)
    args = ["sweep", str(CONFIGS / "random.toml"), "--out", str(tmp_path / "S"), "--n", "1", *flag]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 0, result.output
    assert seen["progress"] is progress

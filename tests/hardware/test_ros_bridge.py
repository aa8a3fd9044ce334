"""The hardware path end to end: roscore on loopback, the MuJoCo driver stand-in, ``tpik-compare hw``.

Times of published and received messages are on the machine's monotonic clock, shared by the
processes, so the stand-in's record gives rates and watchdog reaction times directly.
"""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from tests.hardware.conftest import CONFIGS, ROOT, Proc, read_json, ros_skip_reason, start, write_config

pytestmark = pytest.mark.skipif(ros_skip_reason() is not None, reason=f"ROS 1 not available: {ros_skip_reason()}")

RUN_S = 6.0  # loop time of the case-1 run (scenario.time_scale 0.1: the person steps in at 3.5 s)
TIME_SCALE = 0.1
STATE_PERIOD_S = 0.01
TIMEOUT_S = 90.0


@pytest.fixture(scope="module")
def case1_config(ros_env: dict[str, str], tmp_path_factory: pytest.TempPathFactory) -> Path:
    """configs/case1.toml, short form, tpik only; camera pose and background = the work cell's (perfect calibration)."""
    from compare.hardware.standin import camera_calibration

    d = tmp_path_factory.mktemp("cfg")
    background = d / "background.npz"
    subprocess.run(
        [sys.executable, "-m", "compare.hardware.standin", str(CONFIGS / "case1.toml"), "--write-background",
         str(background)], env=ros_env, cwd=ROOT, check=True, timeout=TIMEOUT_S, capture_output=True,
    )  # fmt: skip
    return write_config(
        d / "case1_hw.toml",
        scenario={"time_scale": TIME_SCALE},
        methods={"names": ["tpik"]},
        hardware={"startup_timeout_s": 60.0, "background_file": str(background), **camera_calibration()},
    )


@pytest.fixture(scope="module")
def live_background_config(case1_config: Path) -> Path:
    """The same, with the background captured from the stand-in's frames at start (0.5 s)."""
    path = case1_config.with_name("case1_live_bg.toml")
    text = case1_config.read_text()
    start = text.index("background_file")
    end = text.index("\n", start)
    path.write_text(text[:start] + "background_capture_s = 0.5" + text[end:])
    return path


def _standin(procs: list[Proc], env: dict[str, str], config: Path, tmp: Path, *extra: str) -> tuple[Proc, Path]:
    record = tmp / "standin_record.json"
    args = ["-m", "compare.hardware.standin", str(config), "--record", str(record), "--duration", "30", *extra]
    return start(procs, env, args, tmp / "standin.log"), record


def _hw(
    env: dict[str, str], config: Path, out: Path, *extra: str, timeout: float = TIMEOUT_S
) -> subprocess.CompletedProcess[str]:
    args = [sys.executable, "-m", "compare.cli", "hw", str(config), "--out", str(out), "-q", *extra]
    return subprocess.run(args, env=env, cwd=ROOT, capture_output=True, text=True, timeout=timeout)


def _stop(proc: Proc, record: Path) -> dict[str, Any]:
    proc.popen.send_signal(signal.SIGTERM)
    proc.popen.wait(timeout=20)
    assert record.exists(), proc.output()[-3000:]
    return read_json(record)


def _measured_safety(steps: Any, summary: dict[str, Any]) -> dict[str, Any]:
    """The simulation's metrics recomputed from measured distances only, as on the hardware path."""
    from compare.analysis.metrics import RunMeta, compute_summary, set_tasks_from_summary

    steps = steps.drop(columns=[c for c in steps.columns if c.startswith(("truth:", "dist_true:"))])
    meta = RunMeta("case1", 0, "tpik", summary["dt"], summary["sim_time_s"], summary["wall_time_s"], "depth",
                   set_tasks_from_summary(summary))  # fmt: skip
    return compute_summary(steps, meta)


def _fmt(g: dict[str, Any]) -> str:
    return (
        f"safety margin {g['safety_margin_min']:+.4f}, physical {g['physical_margin_min']:+.4f}, "
        f"{g['violations']} violations, {g['violation_time_s']:.2f} s"
    )


def _rate(times: list[float], t0: float, t1: float) -> float:
    t = np.array([x for x in times if t0 <= x <= t1])
    return (t.size - 1) / (t[-1] - t[0])


def _first_zero_after(rec: dict[str, Any], t: float) -> tuple[float, bool]:
    """Time of the first all-zero command received after ``t``, and whether every later one is zero."""
    times = np.array(rec["command_t"])
    cmds = np.array(rec["command_deg_s"])
    after = times > t
    zero = ~np.any(cmds, axis=1)
    idx = np.flatnonzero(after & zero)
    assert idx.size, "no zero command after the stall"
    first = int(idx[0])
    return float(times[first]), bool(np.all(zero[first:]))


def test_case1_via_stand_in_is_as_safe_as_in_simulation_at_the_expected_rates(ros_env, procs, case1_config, tmp_path):
    standin, record = _standin(procs, ros_env, case1_config, tmp_path)
    out = tmp_path / "hw"
    res = _hw(ros_env, case1_config, out, "--duration", str(RUN_S))
    rec = _stop(standin, record)
    assert res.returncode == 0, res.stdout[-2000:] + res.stderr[-4000:]
    summary = read_json(out / "summary.json")
    hw = summary["methods"]["tpik"]
    assert (out / "steps").is_dir() and list((out / "plots").glob("*.png"))

    # Rates, measured on both sides, within ±20 % of 100 Hz (states, commands) and 30 Hz (depth).
    rates = hw["hardware"]["rates"]
    assert rates["joint_state"]["rate_hz"] == pytest.approx(100.0, rel=0.2)
    assert rates["depth"]["rate_hz"] == pytest.approx(30.0, rel=0.2)
    t0 = rec["started_t"]
    cmd_rate = _rate(rec["command_t"], t0 + 0.5, t0 + RUN_S - 0.5)
    assert cmd_rate == pytest.approx(100.0, rel=0.2)
    print(f"\nrates: joint_state {rates['joint_state']['rate_hz']:.1f} Hz, depth {rates['depth']['rate_hz']:.1f} Hz, "
          f"commands received {cmd_rate:.1f} Hz")  # fmt: skip

    # Same safety results as the pure simulation of the same scenario (within tolerance).
    sim_out = tmp_path / "sim"
    sim_res = subprocess.run(
        [sys.executable, "-m", "compare.cli", "run", str(case1_config), "--out", str(sim_out), "-q", "--no-plots",
         "--duration", str(RUN_S / TIME_SCALE)],
        env=ros_env, cwd=ROOT, capture_output=True, text=True, timeout=TIMEOUT_S,
    )  # fmt: skip
    assert sim_res.returncode == 0, sim_res.stderr[-3000:]
    from compare.analysis.results import load_steps

    sim = read_json(sim_out / "summary.json")["methods"]["tpik"]
    sim_measured = _measured_safety(load_steps(sim_out, "tpik"), sim)  # the hardware path has no ground truth
    for key, ref in (("joint_limits", sim), ("obstacles", sim_measured)):
        h, m = hw[key], ref[key]
        print(f"{key}: hardware path {_fmt(h)}; simulation {_fmt(m)}")
        assert h["safety_margin_min"] == pytest.approx(m["safety_margin_min"], abs=0.02), key
        assert h["physical_margin_min"] > 0.0 and m["physical_margin_min"] > 0.0, key
        assert h["violation_time_s"] == pytest.approx(m["violation_time_s"], abs=max(0.3, 0.5 * m["violation_time_s"]))
    assert hw["joint_limits"]["violations"] == sim["joint_limits"]["violations"]
    # The stand-in's ground truth agrees with the simulation's.
    truth_min = [rec["truth_min_m"].get(cp) for cp in ("link_4", "link_6", "link_7")]
    print(f"min true distance [m]: hardware path {np.round(truth_min, 4).tolist()}, "
          f"simulation {np.round(sim['min_obstacle_distance_m'], 4).tolist()}")  # fmt: skip
    for d_hw, d_sim in zip(truth_min, sim["min_obstacle_distance_m"], strict=True):
        if d_sim is not None and d_sim < 1.0:
            assert d_hw == pytest.approx(d_sim, abs=0.02)
    assert hw["failures"] == 0


def test_joint_state_stall_zeroes_the_velocity_within_three_periods(ros_env, procs, case1_config, tmp_path):
    stall_at = 1.5
    standin, record = _standin(procs, ros_env, case1_config, tmp_path, "--stop-joint-states-after", str(stall_at))
    res = _hw(ros_env, case1_config, tmp_path / "hw", "--duration", "2.5", "--no-plots")
    rec = _stop(standin, record)
    assert res.returncode == 0, res.stderr[-4000:]
    last_state = max(rec["joint_state_t"])
    t_zero, stays_zero = _first_zero_after(rec, last_state)
    reaction = t_zero - last_state
    print(f"\njoint-state watchdog: zero command {1e3 * reaction:.1f} ms after the last joint state")
    # Stale after 3 state periods; the stream checks every millisecond and sends zero at once.
    assert reaction <= 3 * STATE_PERIOD_S + 0.01
    assert stays_zero
    events = read_json(tmp_path / "hw" / "summary.json")["methods"]["tpik"]["hardware"]["watchdog_events"]
    assert any("joint state stale" in (e["reason"] or "") for e in events), events
    assert "watchdog: zero velocity" in res.stderr and "joint state stale" in res.stderr


def test_depth_stall_zeroes_the_velocity(ros_env, procs, case1_config, tmp_path):
    stall_at = 1.5
    standin, record = _standin(procs, ros_env, case1_config, tmp_path, "--stop-depth-after", str(stall_at))
    res = _hw(ros_env, case1_config, tmp_path / "hw", "--duration", "2.5", "--no-plots")
    rec = _stop(standin, record)
    assert res.returncode == 0, res.stderr[-4000:]
    last_frame = max(rec["depth_t"])
    t_zero, stays_zero = _first_zero_after(rec, last_frame)
    reaction = t_zero - last_frame
    print(f"\ndepth stall: zero command {1e3 * reaction:.1f} ms after the last depth frame")
    # The loop's own stale-frame check (1.5 sensing periods) usually stops first; the 200 ms
    # watchdog of the command stream is the bound.
    assert reaction <= 0.2 + 0.01
    assert stays_zero
    events = read_json(tmp_path / "hw" / "summary.json")["methods"]["tpik"]["hardware"]["watchdog_events"]
    assert any("depth stale" in (e["reason"] or "") for e in events), events
    assert "depth stale" in res.stderr


def test_dry_run_publishes_nothing(ros_env, procs, live_background_config, tmp_path):
    standin, record = _standin(procs, ros_env, live_background_config, tmp_path)
    res = _hw(ros_env, live_background_config, tmp_path / "hw", "--duration", "1", "--dry-run", "--no-plots")
    rec = _stop(standin, record)
    assert res.returncode == 0, res.stderr[-4000:]
    assert rec["command_t"] == []
    summary = read_json(tmp_path / "hw" / "summary.json")["methods"]["tpik"]
    assert summary["hardware"]["dry_run"] and summary["steps"] > 50


def test_start_refused_outside_the_safety_thresholds(ros_env, procs, case1_config, tmp_path, jaco):
    q = jaco.home.copy()
    q[3] = jaco.q_lower[3] + 0.05  # joint 4 inside its physical limit, past the 0.1 rad safety margin
    text = case1_config.read_text().replace("[scenario]", f"[scenario]\nstart_q = {list(map(float, q))}", 1)
    config = tmp_path / "near_limit.toml"
    config.write_text(text)
    standin, record = _standin(procs, ros_env, config, tmp_path)
    res = _hw(ros_env, config, tmp_path / "hw", "--duration", "1", "--no-plots")
    rec = _stop(standin, record)
    assert res.returncode == 2
    assert "outside its safety thresholds" in res.stderr and "joint_limit_4" in res.stderr
    assert not np.any(rec["command_deg_s"])  # only zero velocity ever reached the driver


def test_start_refused_when_the_driver_publishes_at_10_hz(ros_env, procs, case1_config, tmp_path):
    slow = tmp_path / "slow.toml"
    slow.write_text(case1_config.read_text().replace("[hardware]", "[hardware]\nstate_rate_hz = 10.0", 1))
    standin, record = _standin(procs, ros_env, slow, tmp_path)
    res = _hw(ros_env, case1_config, tmp_path / "hw", "--duration", "1", "--no-plots")
    _stop(standin, record)
    assert res.returncode == 2
    assert "feedback_publish_rate:=0.01" in res.stderr


def test_sigint_ends_with_zero_velocity_and_keeps_the_results(ros_env, procs, case1_config, tmp_path):
    standin, record = _standin(procs, ros_env, case1_config, tmp_path)
    out = tmp_path / "hw"
    hw = start(procs, ros_env, ["-m", "compare.cli", "hw", str(case1_config), "--out", str(out), "-q", "--no-plots",
                                "--duration", "20"], tmp_path / "hw.log")  # fmt: skip
    deadline = time.monotonic() + TIMEOUT_S
    while time.monotonic() < deadline and "hardware run" not in hw.output():  # the loop is starting
        time.sleep(0.1)
    time.sleep(1.0)
    t_sig = time.monotonic()
    hw.popen.send_signal(signal.SIGINT)
    assert hw.popen.wait(timeout=30) == 130, hw.output()[-3000:]
    rec = _stop(standin, record)
    t_zero, stays_zero = _first_zero_after(rec, t_sig)
    print(f"\nSIGINT: zero command {1e3 * (t_zero - t_sig):.1f} ms after the signal")
    assert stays_zero and t_zero - t_sig < 0.1
    summary = read_json(out / "summary.json")["methods"]["tpik"]
    assert summary["interrupted"] == "SIGINT" and summary["steps"] > 10

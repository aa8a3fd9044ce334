"""Where a campaign step goes (scripts/loop_parts.py): exclusive times that add up to the whole,
timers that always come off, the parts named in the loop as it is, and the script's command line."""

from __future__ import annotations

import json
import time
from pathlib import Path

import loop_parts
import pandas as pd
import pytest
from loop_parts import (
    OWN_SOLVE,
    PARTS,
    PLANT_PART,
    RANDOM_CONFIG,
    Part,
    PartProfiler,
    check_parts,
    main,
    run_loop_parts,
    stand_ins,
    timers,
)

from compare.config import load_config
from compare.loop import closed_loop
from compare.loop.sim_io import SimRobotIO


class _FakeClock:
    """``time.perf_counter_ns`` that advances only by the work a test says it did (no VM pause in it)."""

    def __init__(self) -> None:
        self.now_ns = 0

    def __call__(self) -> int:
        return self.now_ns

    def work(self, ns: int) -> None:
        self.now_ns += ns


def test_a_part_is_charged_its_time_without_the_timed_parts_it_calls(monkeypatch):
    clock = _FakeClock()
    monkeypatch.setattr(time, "perf_counter_ns", clock)  # read by PartProfiler.wrap
    profiler = PartProfiler(keep_inclusive=("parent",))
    child = profiler.wrap("child", lambda: clock.work(4_000_000))

    def body() -> None:
        clock.work(2_000_000)
        child()
        child()
        clock.work(500_000)

    profiler.wrap("parent", body)()
    parent, kid = profiler.tallies["parent"], profiler.tallies["child"]
    assert (parent.calls, kid.calls) == (1, 2)
    assert (kid.exclusive_ns, parent.exclusive_ns) == (8_000_000, 2_500_000)
    # Nothing counted twice: the exclusive times add up to the outermost call's whole time.
    assert parent.inclusive_ns == [10_500_000]
    assert parent.exclusive_ns + kid.exclusive_ns == parent.inclusive_ns[0]
    assert kid.inclusive_ns == []  # kept only for the labels asked


def test_a_timed_call_that_raises_is_still_charged_and_the_timers_come_off():
    profiler = PartProfiler()
    target = Part("fake", "compare.bench.timing", "summarize")
    import compare.bench.timing as timing

    original = timing.summarize
    with pytest.raises(ZeroDivisionError), timers(profiler, [target]):
        assert timing.summarize is not original
        timing.summarize = profiler.wrap("inner", lambda: 1 / 0)  # replaced again inside: still restored
        timing.summarize()
    assert timing.summarize is original
    assert profiler.tallies["inner"].calls == 1


def test_every_part_names_a_callable_of_the_loop_as_it_is():
    check_parts()  # a renamed loop function fails here, not silently in the table
    with pytest.raises(AttributeError, match="no_such_step"):
        check_parts([Part("gone", "compare.loop.closed_loop", "_Step.no_such_step")])
    methods_before = {p.attribute: loop_parts._owner(p)[0].__dict__.get(loop_parts._owner(p)[1]) for p in PARTS}
    with timers(PartProfiler()):
        pass
    assert {p.attribute: loop_parts._owner(p)[0].__dict__.get(loop_parts._owner(p)[1]) for p in PARTS} == methods_before


def _short_family(tmp_path: Path) -> Path:
    text = RANDOM_CONFIG.read_text().replace("duration_s = 20.0", "duration_s = 0.5", 1)
    assert "duration_s = 0.5" in text
    path = tmp_path / "short.toml"
    path.write_text(text)
    return path


def test_the_parts_of_real_runs_add_up_to_the_runs_and_the_own_solve_is_the_step_tables(tmp_path, monkeypatch):
    config, _ = load_config(_short_family(tmp_path))
    solved: list[float] = []
    own = loop_parts._own_solve_us

    def spy(out_dir: Path, method: str) -> float:
        total = own(out_dir, method)
        table = pd.read_parquet(out_dir / "steps" / f"{method}.parquet")
        solved.append(float(table["solve_time_us"].sum()))
        return total

    monkeypatch.setattr(loop_parts, "_own_solve_us", spy)
    result = run_loop_parts(config, "tpik", [100001, 100002])
    steps_per_run = round(config.scenario.duration_s / config.scenario.dt)
    assert result.steps == 2 * steps_per_run and result.step_us.size == result.steps
    assert result.total_us == pytest.approx(result.runs_us_per_step, rel=1e-9)
    assert result.parts_us[OWN_SOLVE] == pytest.approx(sum(solved) / result.steps)
    assert all(v >= 0.0 for v in result.parts_us.values()), result.parts_us
    assert set(result.parts_us) == {p.label for p in PARTS} | {OWN_SOLVE}
    assert result.unprofiled_cpu_us_per_step > 0.0 and result.timed_calls_per_step > 10


def test_on_the_cpu_clock_the_own_solve_is_timed_on_the_methods_solve_and_the_parts_still_add_up(tmp_path):
    config, _ = load_config(_short_family(tmp_path))
    result = run_loop_parts(config, "hqp-daqp", [100001], clock="cpu")
    assert result.total_us == pytest.approx(result.runs_us_per_step, rel=1e-9)
    assert set(result.parts_us) == {p.label for p in PARTS} | {OWN_SOLVE}
    assert all(v >= 0.0 for v in result.parts_us.values()), result.parts_us
    # The solve is most of a step's CPU outside the plant, and no more than the whole step.
    assert 0.0 < result.parts_us[OWN_SOLVE] < float(result.step_us.mean())
    assert result.shared_loop_us(0.0) == pytest.approx(
        result.total_us - result.parts_us[PLANT_PART] - result.parts_us[OWN_SOLVE]
    )


def test_the_script_writes_its_entry_and_refuses_an_unknown_method_in_one_line(tmp_path, capsys):
    family = _short_family(tmp_path)
    out = tmp_path / "loop.json"
    argv = ["--family", str(family), "--json", str(out), "--seed", "100001"]
    assert main([*argv, "-m", "tpik"]) == 0
    payload = json.loads(out.read_text())
    (row,) = payload["results"]
    assert (row["name"], row["case"]) == ("loop-step", "tpik")
    assert payload["command"] == f"python scripts/loop_parts.py {' '.join(argv)} -m tpik"
    entry = payload["loop_parts"]
    assert entry["config"] == str(family) and entry["seeds"] == [100001]
    assert entry["clock"] == "wall"
    tpik = entry["methods"]["tpik"]
    assert tpik["total_us_per_step"] == pytest.approx(sum(tpik["parts_us_per_step"].values()))
    assert tpik["shared_loop_us_per_step"] > 0.0
    capsys.readouterr()
    assert main([*argv, "-m", "no-such-method"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and "no-such-method" in err


def test_a_method_that_fails_in_its_runs_is_one_error_not_a_traceback(tmp_path, monkeypatch, capsys):
    import compare.run

    def broken(*args, **kwargs):
        raise RuntimeError("solver exploded")

    monkeypatch.setattr(compare.run, "run_method", broken)
    family = _short_family(tmp_path)
    assert main(["--family", str(family), "-m", "tpik", "--seed", "100001"]) == 2
    err = capsys.readouterr().err
    assert "error: loop parts of tpik" in err and "solver exploded" in err and "Traceback" not in err


def test_stand_ins_leave_the_loops_own_code_and_are_always_taken_off(tmp_path):
    config, _ = load_config(_short_family(tmp_path))
    wait, solve = SimRobotIO.__dict__["wait"], closed_loop.timed_solve
    both = run_loop_parts(config, "tpik", [100001], stand_in="both")
    assert SimRobotIO.__dict__["wait"] is wait and closed_loop.timed_solve is solve
    real = run_loop_parts(config, "tpik", [100001])
    assert both.steps == real.steps
    # No physics and no solve: the plant's row is a clock update, the own solve nothing.
    assert both.parts_us[OWN_SOLVE] == 0.0 < real.parts_us[OWN_SOLVE]
    assert both.parts_us[PLANT_PART] < 0.2 * real.parts_us[PLANT_PART]
    with pytest.raises(ValueError, match="stand-in must be one of"), stand_ins("physics"):
        pass
    with pytest.raises(ZeroDivisionError), stand_ins("solve"):
        assert closed_loop.timed_solve is not solve
        _ = 1 / 0
    assert closed_loop.timed_solve is solve

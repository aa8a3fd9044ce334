"""Setups compared on the same seeds: held rates, the paired McNemar counts, mission cost, the CLI."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from compare.analysis.results import sweep_run_dir
from compare.campaign.setups import compare_setups, main


def _sweep(
    root: Path,
    held: dict[int, bool],
    ee: float,
    label: str | None = "avoidable",
    times: dict[int, list[float | None]] | None = None,
) -> Path:
    """A sweep of one method whose run of seed s held the threshold when ``held[s]``.

    The person's torso peaks at 1 + 0.1·s m/s; ``times[s]`` is the run's time to each waypoint.
    """
    for k, (seed, ok) in enumerate(sorted(held.items())):
        run = sweep_run_dir(root, k)
        run.mkdir(parents=True)
        method = {
            "obstacles": {"violations": 0 if ok else 3, "physical_violation_time_s": 0.0 if ok else 0.2},
            "joint_limits": {"violations": 0, "safety_margin_min": 0.01 + 0.001 * k},
            "walls": {"violations": int(k == 0), "safety_margin_min": -0.002 if k == 0 else 0.01},
            "ee_error_m": {"mean": ee + 0.001 * k, "final": 0.0},
            "waypoints_reached": 2,
            "time_to_waypoint_s": (times or {}).get(seed, [1.0, 2.0]),
        }
        person = {"max_speed_mps": {"torso": 1.0 + 0.1 * seed, "hand": 3.0}}
        summary = {"seed": seed, "methods": {"tpik": method}, "oracle": {"label": label}, "person": person}
        (run / "summary.json").write_text(json.dumps(summary), encoding="utf-8")
    return root


def test_paired_counts_rates_and_mission_cost(tmp_path: Path) -> None:
    off = _sweep(tmp_path / "off", {s: s < 2 for s in range(10)}, ee=0.20)  # held 0, 1
    on = _sweep(tmp_path / "on", {s: s % 2 == 0 for s in range(12)}, ee=0.25)  # held 0, 2, 4, 6, 8 (+10)
    result = compare_setups([("off", off), ("on", on)])
    m = result["methods"]["tpik"]
    assert m["paired_runs"] == 10 and m["seeds"] == [0, 9]  # seeds 10, 11 are not in the baseline
    e_on, e_off = m["setups"]["on"], m["setups"]["off"]
    assert e_on["held"]["count"] == 5 and e_off["held"]["count"] == 2
    assert e_on["held"]["ci95"][0] < 0.5 < e_on["held"]["ci95"][1]
    assert e_on["held_avoidable"]["count"] == 5
    assert (e_on["vs_baseline"]["only_this"], e_on["vs_baseline"]["only_baseline"]) == (4, 1)  # 2,4,6,8 / 1
    assert e_on["vs_baseline"]["mcnemar_p"] == pytest.approx(0.375)
    assert e_on["ee_error_mean_m"] == pytest.approx(0.25 + 0.0045)
    assert e_on["ee_error_vs_baseline_wilcoxon_p"] < 0.01  # 0.05 m more, every seed
    assert e_on["wall_violations"] == 1 and e_on["wall_margin_min_m"] == pytest.approx(-0.002)


def test_first_seeds_pairs_only_the_first_shared_seeds(tmp_path: Path) -> None:
    off = _sweep(tmp_path / "off", {s: s < 2 for s in range(10)}, ee=0.20)  # held 0, 1
    on = _sweep(tmp_path / "on", {s: s % 2 == 0 for s in range(12)}, ee=0.25)  # held 0, 2, 4, ...
    m = compare_setups([("off", off), ("on", on)], first_seeds=4)["methods"]["tpik"]
    assert m["paired_runs"] == 4 and m["seeds"] == [0, 3]
    assert m["setups"]["on"]["held"]["count"] == 2 and m["setups"]["off"]["held"]["count"] == 2  # 0, 2 / 0, 1
    vs = m["setups"]["on"]["vs_baseline"]
    assert (vs["only_this"], vs["only_baseline"]) == (1, 1)
    assert main([f"{off}:off", f"{on}:on", "--seeds", "4", "--out", str(tmp_path / "out")]) == 0
    written = json.loads((tmp_path / "out" / "setups.json").read_text(encoding="utf-8"))
    assert written["methods"]["tpik"]["seeds"] == [0, 3]


def test_no_verdict_no_avoidable_rate_and_bad_input_is_one_line(tmp_path: Path, capsys) -> None:
    a = _sweep(tmp_path / "a", {0: True, 1: False}, ee=0.1, label=None)
    b = _sweep(tmp_path / "b", {0: False, 1: False}, ee=0.1, label=None)
    assert compare_setups([("a", a), ("b", b)])["methods"]["tpik"]["setups"]["b"]["held_avoidable"] is None
    for args, message in (
        ([str(a), str(tmp_path / "missing")], "missing: no such directory or run table"),
        ([str(a), str(tmp_path)], "no runs/ directory"),
        ([f"{a}:x", f"{b}:x"], "seed 0, tpik differs between"),
        ([f"{a}:x", f"{a}:x"], "at least two setups"),
        ([str(a), str(b), "--seeds", "0"], "--seeds"),
    ):
        with pytest.raises(SystemExit) as exit_:
            main([*args, "--out", str(tmp_path / "out")])
        assert exit_.value.code == 2 and message in capsys.readouterr().err
    assert main([f"{a}:a", f"{b}:b", "--out", str(tmp_path / "out")]) == 0
    assert "| `tpik` | b | 2 |" in (tmp_path / "out" / "setups.md").read_text(encoding="utf-8")


def test_time_to_waypoint_paired_and_reached_only_once(tmp_path: Path) -> None:
    base_times = {s: [1.0, 2.0, None] for s in range(6)}
    slower = {s: [1.5, None, 3.0] if s == 0 else [1.5, 2.5, None] for s in range(6)}  # +0.5 s on every segment
    off = _sweep(tmp_path / "off", {s: True for s in range(6)}, ee=0.2, times=base_times)
    on = _sweep(tmp_path / "on", {s: True for s in range(6)}, ee=0.2, times=slower)
    wt = compare_setups([("off", off), ("on", on)])["methods"]["tpik"]["setups"]["on"]["waypoint_time"]
    assert wt["seeds"] == 6
    assert wt["mean_s"] - wt["baseline_mean_s"] == pytest.approx(0.5)
    assert wt["wilcoxon_p"] < 0.05  # slower on every seed
    assert (wt["only_this"], wt["only_baseline"]) == (1, 1)  # seed 0: segment 2 here, segment 1 there


def test_held_by_speed_bins_and_plot(tmp_path: Path) -> None:
    off = _sweep(tmp_path / "off", {s: False for s in range(8)}, ee=0.2)
    on = _sweep(tmp_path / "on", {s: s < 4 for s in range(8)}, ee=0.2)  # holds the four slowest
    result = compare_setups([("off", off), ("on", on)])
    bins = result["methods"]["tpik"]["setups"]["on"]["held_by_torso_speed"]
    assert sum(b["held"]["runs"] for b in bins) == 8  # every run in exactly one bin
    assert bins[0]["held"]["rate"] == 1.0 and bins[-1]["held"]["rate"] == 0.0
    assert bins[0]["low"] == pytest.approx(1.0) and bins[-1]["high"] == pytest.approx(1.7)
    assert main([f"{off}:off", f"{on}:on", "--out", str(tmp_path / "out")]) == 0
    report = (tmp_path / "out" / "setups.md").read_text(encoding="utf-8")
    assert "peak torso speed" in report and "(2/2)" in report
    assert (tmp_path / "out" / "setups_speed.png").stat().st_size > 0


def test_speed_plot_wraps_methods_onto_rows_of_three(tmp_path: Path, monkeypatch) -> None:
    import compare.analysis.plots_setups as plots_setups

    off = _sweep(tmp_path / "off", {s: False for s in range(8)}, ee=0.2)
    on = _sweep(tmp_path / "on", {s: s < 4 for s in range(8)}, ee=0.2)
    result = compare_setups([("off", off), ("on", on)])
    entry = result["methods"]["tpik"]
    result["methods"] = {f"m{k}": entry for k in range(4)}
    kept = []
    monkeypatch.setattr(plots_setups, "save_figure", lambda fig, path: kept.append(fig) or path)
    plots_setups.plot_held_by_speed(result, tmp_path / "speed.png")
    shown = [ax for ax in kept[0].axes if ax.get_visible()]
    assert [ax.get_title() for ax in shown] == [f"m{k} (8 seeds)" for k in range(4)]
    assert len(kept[0].axes) == 6  # 2 rows x 3 columns, the last two hidden
    assert len({round(ax.get_position().y0, 3) for ax in shown}) == 2

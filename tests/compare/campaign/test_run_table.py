"""Run tables: a sweep's rows kept in a file, read back exactly, merged across sweeps with checks."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from compare.analysis.results import MANIFEST_FILE, sweep_run_dir
from compare.campaign.run_table import load_table, merge_tables, read_table, sweep_table, write_table
from compare.campaign.setups import compare_setups, main


def _sweep(root: Path, seeds: range, ee: float = 0.1, fingerprint: dict | None = None, flip: int | None = None) -> Path:
    """A sweep of tpik and mink on ``seeds`` with a manifest; seed ``flip`` breaks its tpik row."""
    for k, seed in enumerate(seeds):
        run = sweep_run_dir(root, k)
        run.mkdir(parents=True)
        methods = {
            name: {
                "obstacles": {"violations": (seed + j) % 3, "physical_violation_time_s": 0.01 * seed},
                "joint_limits": {"violations": 0, "safety_margin_min": 1.0 / (seed + 3)},
                "walls": {"violations": 0, "safety_margin_min": None},
                "ee_error_m": {"mean": ee + math.pi * 1e-3 * seed + (1e-12 if seed == flip and j == 0 else 0.0)},
                "waypoints_reached": 1 + seed % 2,
                "time_to_waypoint_s": [0.1 * seed + 1.0 / 3.0, None],
            }
            for j, name in enumerate(("tpik", "mink"))
        }
        label = "avoidable" if seed % 2 else None
        summary = {
            "seed": seed,
            "methods": methods,
            "oracle": {"label": label},
            "person": {"max_speed_mps": {"torso": 1.0 + seed / 7}},
        }
        (run / "summary.json").write_text(json.dumps(summary), encoding="utf-8")
    manifest = {
        "config_hash": "x",
        "config_fingerprint": {"scenario.seed": seeds.start, "sensor.rho_m": 0.5, **(fingerprint or {})},
        "scenario": "random",
        "plant": {"sensing": "depth"},
        "method_settings": {"tpik": {}, "mink": {}},
        "versions": {"project": "0.1.0", "git_commit": "abc"},
    }
    (root / MANIFEST_FILE).write_text(json.dumps(manifest), encoding="utf-8")
    return root


def test_table_round_trips_exactly(tmp_path: Path) -> None:
    table = sweep_table(_sweep(tmp_path / "s", range(10, 16)))
    assert len(table.rows) == 12 and table.provenance["config_fingerprint"] == {"sensor.rho_m": 0.5}
    assert table.provenance["sources"][0]["seeds"] == [10, 15] and table.provenance["sources"][0]["git_commit"] == "abc"
    csv, meta = write_table(table, tmp_path / "off.csv")
    back = read_table(csv)
    assert back.provenance == json.loads(meta.read_text(encoding="utf-8"))
    a = table.rows.sort_values(["seed", "method"]).reset_index(drop=True)
    b = back.rows
    for column in a.columns:
        for x, y in zip(a[column], b[column], strict=True):
            if isinstance(x, list):
                assert len(x) == len(y) and all(
                    (p == q) or (math.isnan(p) and math.isnan(q)) for p, q in zip(x, y, strict=True)
                )
            elif isinstance(x, float) and math.isnan(x):
                assert math.isnan(y)
            else:
                assert x == y and type(bool(x)) is type(bool(y)), column  # floats exact, not rounded
    assert b["label"].isna().tolist()[:3] == [True, True, False] and b["label"].tolist()[2] == "avoidable"


def test_merge_unions_and_refuses_changed_runs_or_config(tmp_path: Path) -> None:
    first = sweep_table(_sweep(tmp_path / "a", range(0, 6)))
    second = sweep_table(_sweep(tmp_path / "b", range(4, 10)))  # seeds 4, 5 run twice, the same
    merged = merge_tables([first, second])
    assert sorted(set(merged.rows["seed"])) == list(range(10)) and len(merged.rows) == 20
    assert [s["seeds"] for s in merged.provenance["sources"]] == [[0, 5], [4, 9]]
    again = merge_tables([merged, sweep_table(tmp_path / "b")])  # the same sweep once more: listed once
    assert [s["seeds"] for s in again.provenance["sources"]] == [[0, 5], [4, 9]] and len(again.rows) == 20
    changed = sweep_table(_sweep(tmp_path / "c", range(5, 8), flip=5))
    with pytest.raises(ValueError, match=r"seed 5, tpik differs .*ee_error_mean"):
        merge_tables([first, changed], what="off")
    other = sweep_table(_sweep(tmp_path / "d", range(20, 22), fingerprint={"sensor.rho_m": 0.95}))
    with pytest.raises(ValueError, match=r"another configuration \(sensor\.rho_m: 0\.5 → 0\.95\)"):
        merge_tables([first, other])
    newer = sweep_table(_sweep(tmp_path / "e", range(20, 22), fingerprint={"loop.new_key": 1}))
    assert len(merge_tables([first, newer]).rows) == 16  # a key one side lacks is no conflict


def test_setups_from_saved_tables_equal_setups_from_sweeps(tmp_path: Path) -> None:
    """A campaign split in two sweeps per setup, saved, then grown from the tables: the same result."""
    off_1, off_2 = _sweep(tmp_path / "off1", range(0, 8)), _sweep(tmp_path / "off2", range(8, 14))
    on_1, on_2 = _sweep(tmp_path / "on1", range(0, 8), ee=0.2), _sweep(tmp_path / "on2", range(8, 14), ee=0.2)
    whole = compare_setups([("off", off_1), ("off", off_2), ("on", on_1), ("on", on_2)])
    out = tmp_path / "out"
    assert main([f"{off_1}:off", f"{on_1}:on", "--out", str(out), "--save-runs"]) == 0
    assert load_table(out / "runs" / "off.csv").rows["seed"].max() == 7
    grown = compare_setups(
        [("off", out / "runs" / "off.csv"), ("off", off_2), ("on", out / "runs" / "on.csv"), ("on", on_2)]
    )
    assert grown["methods"] == whole["methods"]
    assert grown["methods"]["tpik"]["paired_runs"] == 14
    assert grown["setups"]["off"].endswith("off.csv + " + str(off_2))

"""One vs two cameras on the same seeds: pairing, rates, tests and figure on hand-built sweeps."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from matplotlib.image import imread
from scipy import stats

from compare.analysis.results import STEPS_DIR, sweep_run_dir
from compare.campaign.cameras import FIGURE, RESULT, compare_sweeps, main


def _sweep(root: Path, runs: list[tuple[int, bool, float, float]]) -> Path:
    """Runs (seed, violation, physical time [s], occluded share) of method tpik."""
    for i, (seed, violation, physical_s, occluded) in enumerate(runs):
        run_dir = sweep_run_dir(root, i)
        (run_dir / STEPS_DIR).mkdir(parents=True)
        obstacles = {"violations": int(violation), "physical_violation_time_s": physical_s}
        summary = {"scenario": "random", "seed": seed, "methods": {"tpik": {"obstacles": obstacles}}}
        (run_dir / "summary.json").write_text(json.dumps(summary))
        n = 100
        flags = np.arange(n) < round(occluded * n)
        steps = pd.DataFrame({"t": np.arange(n) * 0.01, "occluded:link_4": flags, "occluded:link_6": False})
        steps.to_parquet(run_dir / STEPS_DIR / "tpik.parquet")
    return root


def test_runs_are_paired_by_seed_and_the_tests_are_the_libraries(tmp_path):
    rng = np.random.default_rng(0)
    seeds = list(range(30))
    v1 = rng.random(30) < 0.5
    v2 = v1 & (rng.random(30) < 0.4)  # the second camera removes most violations
    t1 = rng.uniform(0.0, 0.5, 30)
    t2 = t1 * 0.3
    one = _sweep(tmp_path / "one", [(s, v1[i], t1[i], 0.2) for i, s in enumerate(seeds)])
    # The two-camera sweep lacks seed 29 and has an extra seed 99: neither is paired.
    runs_two = [(s, v2[i], t2[i], 0.05) for i, s in enumerate(seeds[:-1])] + [(99, True, 9.0, 0.0)]
    two = _sweep(tmp_path / "two", runs_two)
    out = compare_sweeps(one, two)["methods"]["tpik"]
    assert out["paired_runs"] == 29
    k1, k2 = int(v1[:29].sum()), int(v2[:29].sum())
    assert out["violation"]["one"]["count"] == k1 and out["violation"]["two"]["count"] == k2
    wilson = stats.binomtest(k1, 29).proportion_ci(method="wilson")
    assert out["violation"]["one"]["ci95"] == pytest.approx([wilson.low, wilson.high])
    only_one = int(np.count_nonzero(v1[:29] & ~v2[:29]))
    assert out["violation"]["only_one"] == only_one and out["violation"]["only_two"] == 0
    assert out["violation"]["mcnemar_p"] == pytest.approx(stats.binomtest(only_one, only_one, 0.5).pvalue)
    assert out["physical_time_s"]["one"]["mean"] == pytest.approx(t1[:29].mean())
    assert out["physical_time_s"]["wilcoxon_p"] == pytest.approx(stats.wilcoxon(t1[:29], t2[:29]).pvalue)
    assert out["occluded_share"] == {"one": pytest.approx(0.2), "two": pytest.approx(0.05)}


def test_the_command_writes_json_and_figure_and_refuses_a_non_sweep(tmp_path, capsys):
    one = _sweep(tmp_path / "one", [(s, s % 2 == 0, 0.1 * s, 0.1) for s in range(6)])
    two = _sweep(tmp_path / "two", [(s, s % 3 == 0, 0.05 * s, 0.0) for s in range(6)])
    assert main([str(one), str(two), "--out", str(tmp_path / "out")]) == 0
    result = json.loads((tmp_path / "out" / RESULT).read_text())
    assert result["methods"]["tpik"]["paired_runs"] == 6
    img = imread(tmp_path / "out" / FIGURE)
    assert img.shape[1] >= 800 and img.shape[0] >= 300
    with pytest.raises(SystemExit) as exit_:
        main([str(tmp_path / "missing"), str(two), "--out", str(tmp_path / "x")])
    assert exit_.value.code == 2 and "missing: no such directory" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exit_:
        main([str(tmp_path), str(two), "--out", str(tmp_path / "x")])
    assert exit_.value.code == 2 and "not a sweep" in capsys.readouterr().err

"""docs/design.md names every key of the machine-readable outputs and keeps its section numbers.

The keys come from the reference files the code wrote (``tests/compare/analysis/reference/``,
which ``test_summary_reference.py`` keeps equal to what a run writes today) and from the bench's
JSON writer, so a key added to an output and not to the document fails here.
"""

from __future__ import annotations

import json
import re
from dataclasses import fields
from pathlib import Path

from compare.bench.correctness import Summary
from compare.bench.timing import BenchRow

ROOT = Path(__file__).resolve().parents[1]
DESIGN = ROOT / "docs" / "design.md"
REFERENCE = ROOT / "tests" / "compare" / "analysis" / "reference"


def _named() -> set[str]:
    return set(re.findall(r"`([^`]+)`", DESIGN.read_text(encoding="utf-8")))


def test_sections_one_to_seven_keep_their_numbers():
    headings = re.findall(r"^## (\d+)\. ", DESIGN.read_text(encoding="utf-8"), re.M)
    assert headings[:7] == [str(n) for n in range(1, 8)]


def test_every_summary_key_is_named():
    named = _named()
    run = json.loads((REFERENCE / "case2_run.json").read_text())
    method = next(iter(run["methods"].values()))
    missing = [k for k in [*run, *method, *method["joint_limits"], *method["iso15066"]] if k not in named]
    assert not missing, f"summary.json keys docs/design.md §7 does not name: {missing}"


def test_every_sweep_summary_key_is_named():
    named = _named()
    sweep = json.loads((REFERENCE / "sweep_summary.json").read_text())
    method = next(iter(sweep["methods"].values()))
    pair = next(iter(sweep["paired"].values()))
    keys = [*sweep, *sweep["campaign"], *method, *pair, *pair["obstacle_violation"]]
    missing = [k for k in keys if k not in named]
    assert not missing, f"sweep_summary.json keys docs/design.md §7 does not name: {missing}"


def test_every_bench_json_key_is_named():
    named = _named()
    keys = ["versions", "command", "robot", "results", "correctness", "throughput_ceiling", "loop_parts"]
    keys += [f.name for f in fields(BenchRow)]
    keys += ["success_rate", "qpbenchmark_success", "flagged", "silent", "time_us"]
    assert {f.name for f in fields(Summary)} >= {"success_rate", "qpbenchmark_success", "flagged", "silent"}
    missing = [k for k in keys if k not in named]
    assert not missing, f"bench --json keys docs/design.md §7 does not name: {missing}"

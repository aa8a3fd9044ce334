"""The paper-claims tables: a cell is ✓ only when the claim held in every seed's run, per variant."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from typer.testing import CliRunner

from compare.analysis.claims import Claim
from compare.analysis.claims_tables import claims_markdown
from compare.campaign.paper_claims import ClaimRuns, claims_details, claims_json, claims_tables
from compare.cli import app


def _claim(key: str, holds: bool, measured: str = "m") -> Claim:
    return Claim(key, f"the {key} claim", holds, measured, {"x": 1.0})


def test_a_cell_holds_only_when_every_seed_held_and_shows_both_variants():
    results = {
        "case1": {
            "case config": {
                "tpik": {"c1_a": ClaimRuns((_claim("c1_a", True), _claim("c1_a", True)))},
                "mink": {"c1_a": ClaimRuns((_claim("c1_a", True), _claim("c1_a", False)))},
            },
            "paper-paced": {"tpik": {"c1_a": ClaimRuns((_claim("c1_a", False), _claim("c1_a", False)))}},
        }
    }
    text = claims_tables(results, [0, 1])
    lines = text.splitlines()
    assert lines[0] == "| case1 claim | tpik | mink |"
    assert lines[2] == "| the c1_a claim | ✓ / ✗ | ✗ / – |"
    assert "every seed (0, 1)" in lines[-1]
    assert "| case1 | case config | mink | c1_a | ✗ | m ; m |" in claims_details(results)
    assert claims_json(results)["case1"]["case config"]["mink"]["c1_a"]["holds"] is False


def test_missing_case_configs_are_one_line_and_exit_2(tmp_path):
    result = CliRunner().invoke(app, ["paper-claims", "--configs", str(tmp_path), "--out", str(tmp_path / "o")])
    assert result.exit_code == 2 and "missing case configs case1.toml" in result.output


@pytest.mark.parametrize("name", ["claims", "claims-predicted"])
def test_the_tables_written_match_the_json_written(name: str) -> None:
    """claims.md's tables are those of claims.json (the README and docs tables are generated from the JSON)."""
    root = Path(__file__).resolve().parents[3] / "docs" / "separating"
    written = (root / f"{name}.md").read_text(encoding="utf-8")
    data = json.loads((root / f"{name}.json").read_text(encoding="utf-8"))
    assert written.split("\n\n(each cell:")[0].strip() == claims_markdown(data)

"""A run's report.md: the results table read from summary.json, the plots that exist, a case's claims."""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

from typer.testing import CliRunner

from compare.analysis.claims import claims_for_run
from compare.analysis.metrics import registered_metrics
from compare.analysis.run_report import render_run_report
from compare.cli import app

CONFIGS = Path(__file__).resolve().parents[3] / "configs"


def report_table(text: str) -> dict[str, dict[str, str]]:
    """The Results table of a report.md: {method: {header: cell}}."""
    section = text.split("## Results", 1)[1].split("\n## ", 1)[0]
    lines = [line for line in section.splitlines() if line.startswith("|")]
    split = [[cell.strip().replace("\\|", "|") for cell in re.split(r"(?<!\\)\|", line)[1:-1]] for line in lines]
    headers, rows = split[0], split[2:]
    return {row[0]: dict(zip(headers[1:], row[1:], strict=True)) for row in rows}


def assert_table_is_the_summary(run_dir: Path) -> None:
    """The report's table has one row per method of summary.json, with its figures."""
    summary = json.loads((run_dir / "summary.json").read_text())
    table = report_table((run_dir / "report.md").read_text())
    assert set(table) == set(summary["methods"])
    for name, m in summary["methods"].items():
        row = table[name]
        assert row["solve median [µs]"] == f"{m['solve_time_us']['median']:.1f}"
        assert row["solve p99 [µs]"] == f"{m['solve_time_us']['p99']:.1f}"
        assert row["EE final error [m]"] == f"{m['ee_error_m']['final']:.4f}"
        assert row["joint margin [rad]"].split()[0] == f"{m['joint_limits']['safety_margin_min']:+.3f}"
        assert row["obstacle margin [m]"].split()[0] == f"{m['obstacles']['safety_margin_min']:+.3f}"
        closest = min(d for d in m["min_obstacle_distance_m"] if d is not None and math.isfinite(d))
        assert row["min obstacle dist. [m]"] == f"{closest:.3f}"
        steps = f"{m['status_steps']['degraded']} / {m['failures']} / {m['fallbacks']}"
        assert row["degraded / failed / fallback steps"] == steps
        # Every other column as the terminal table shows it: the registered metrics' cells.
        columns = [c for metric in registered_metrics() for c in metric.run_table(list(summary["methods"].values()))]
        assert row == {c.header: c.cell(m) for c in columns}


def test_a_case_run_reports_its_table_plots_and_claims(tmp_path):
    """Case 1 in short form (its events five times faster, 14 s): every claim per method, every plot linked."""
    out = tmp_path / "case1"
    args = ["run", str(CONFIGS / "case1.toml"), "--time-scale", "0.2", "--sensing", "geometric", "-m", "tpik"]
    result = CliRunner().invoke(app, [*args, "--out", str(out), "-q"])
    assert result.exit_code == 0, result.output
    assert f"report:  {out}/report.md" in result.output
    assert_table_is_the_summary(out)
    text = (out / "report.md").read_text()
    links = re.findall(r"\]\((plots/[^)]+)\)", text)
    assert links and sorted(links) == sorted(p.relative_to(out).as_posix() for p in (out / "plots").glob("*.png"))
    claims = claims_for_run(out)["tpik"]
    assert len(claims) == 6
    section = text.split("## The paper's claims (Sec. IV)", 1)[1]
    for claim in claims:
        row = f"| {claim.claim} | tpik | {'✓' if claim.holds else '✗'} {claim.measured} |"
        assert row in section
    assert "Not checked" not in section


def test_a_report_links_only_the_plots_there_and_names_failed_methods(tmp_path):
    summary = {
        "scenario": "s",
        "seed": 3,
        "sim_time_s": 1.0,
        "methods": {"tpik": {"solve_time_us": {"median": 12.34, "p99": 50.0}, "ee_error_m": {"final": 0.01234}}},
        "errors": {"mink": "ValueError: no\nsecond line"},
    }
    (tmp_path / "summary.json").write_text(json.dumps(summary))
    (tmp_path / "plots").mkdir()
    (tmp_path / "plots" / "tpik_joints.png").write_bytes(b"")
    text = render_run_report(tmp_path).read_text()
    table = report_table(text)
    assert table["tpik"]["solve median [µs]"] == "12.3" and table["tpik"]["EE final error [m]"] == "0.0123"
    assert list(table["mink"].values())[0] == "failed: ValueError: no"
    assert re.findall(r"\]\(([^)]+\.png)\)", text) == ["plots/tpik_joints.png"]
    assert "claims" not in text  # no config: no claims


def test_a_report_without_plots_says_how_to_draw_them(tmp_path):
    (tmp_path / "summary.json").write_text(json.dumps({"scenario": "s", "seed": 0, "methods": {}}))
    text = render_run_report(tmp_path).read_text()
    assert f"No plots: `tpik-compare plot {tmp_path}` draws them." in text

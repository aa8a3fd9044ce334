"""README.md's and the docs' result tables are those the committed results files give (make docs-figures)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from compare.analysis.readme_figures import BEGIN, FIGURES, FiguresError, fill, generate, main, p_value, stale

ROOT = Path(__file__).resolve().parents[1]


def test_every_generated_table_is_up_to_date():
    assert not stale(ROOT), "result tables out of date: make docs-figures (python -m compare.analysis.readme_figures)"


def test_the_fair_campaign_and_prediction_tables_are_generated():
    def names(rel: str) -> set[str]:
        return {m.group(1) for m in BEGIN.finditer((ROOT / rel).read_text(encoding="utf-8"))}

    assert names("README.md") == {"fair-campaign", "paper-claims"}
    in_separating = {
        "predicted-campaign",
        "depth-campaign",
        "depth-vs-geometric",
        "paper-claims",
        "paper-claims-predicted",
    }
    assert names("docs/separating.md") == in_separating
    everything = {"fair-campaign", *in_separating}
    assert {f.name for f in FIGURES} == everything


def _checkout(tmp_path: Path) -> Path:
    """A copy of the documents and results files the tables are made of."""
    for rel in ["README.md", "docs/separating.md", *(f.source for f in FIGURES)]:
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(ROOT / rel, tmp_path / rel)
    return tmp_path


def test_a_changed_results_file_makes_its_table_stale_and_the_command_rewrites_it(tmp_path, capsys):
    root = _checkout(tmp_path)
    source = root / "docs/campaign-fair/sweep_summary.json"
    summary = json.loads(source.read_text(encoding="utf-8"))
    summary["methods"]["mink"]["time_below_physical_s"] = 99.94
    source.write_text(json.dumps(summary), encoding="utf-8")
    assert stale(root) == [root / "README.md"]
    assert main(["--check", "--root", str(root)]) == 1
    assert "README.md is out of date: make docs-figures" in capsys.readouterr().err
    assert main(["--root", str(root)]) == 0
    assert "| `mink` | 1/1000 | 90.2 % | 0 | 99.9 s |" in (root / "README.md").read_text(encoding="utf-8")
    assert main(["--check", "--root", str(root)]) == 0
    # Outside the markers nothing moved.
    before, after = (ROOT / "README.md").read_text(encoding="utf-8"), (root / "README.md").read_text(encoding="utf-8")
    assert before.replace("| 22.8 s |", "| 99.9 s |") == after


def test_an_edited_table_is_stale(tmp_path):
    root = _checkout(tmp_path)
    doc = root / "docs/separating.md"
    text = doc.read_text(encoding="utf-8")
    start = text.index("<!-- figures:predicted-campaign -->")
    row = text.index("| `tpik` |", start)
    doc.write_text(text[:row] + "| `tpik` | 99.9 % " + text[row + len("| `tpik` |") :])  # a cell edited by hand
    assert stale(root) == [doc]


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("<!-- figures:nope -->\n| a |\n<!-- /figures -->\n", "doc: <!-- figures:nope --> names no figure"),
        ("<!-- figures:fair-campaign -->\n| a |\n", "doc: <!-- figures:fair-campaign --> has no <!-- /figures -->"),
    ],
)
def test_a_bad_marker_is_one_error_naming_it(text, message):
    with pytest.raises(FiguresError, match=message):
        fill(text, {"fair-campaign": "| t |"}, "doc")


def test_bad_input_is_one_line_and_exit_2(tmp_path, capsys):
    assert main(["--root", str(tmp_path)]) == 2
    assert capsys.readouterr().err == f"error: {tmp_path}: no README.md (not a checkout of the project)\n"
    root = _checkout(tmp_path / "c")
    (root / "docs/campaign-predicted/setups.json").write_text("{", encoding="utf-8")
    assert main(["--root", str(root)]) == 2
    assert capsys.readouterr().err.count("\n") == 1
    with pytest.raises(SystemExit) as exit_:
        main(["--no-such-option"])
    assert exit_.value.code == 2 and capsys.readouterr().err == "error: unrecognized arguments: --no-such-option\n"


def test_a_figure_in_no_document_is_an_error(tmp_path):
    root = _checkout(tmp_path)
    readme = root / "README.md"
    readme.write_text(readme.read_text(encoding="utf-8").replace("<!-- figures:fair-campaign -->", ""))
    with pytest.raises(FiguresError, match="no document holds <!-- figures:fair-campaign -->"):
        generate(root)


@pytest.mark.parametrize(
    ("p", "text"), [(0.058, "0.058"), (1.0, "1"), (2.49e-60, "2·10⁻⁶⁰"), (1.2e-63, "10⁻⁶³"), (9.34e-43, "9·10⁻⁴³")]
)
def test_p_values_are_printed_as_the_docs_print_them(p, text):
    assert p_value(p) == text

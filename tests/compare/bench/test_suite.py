"""The bench's options: checked where they are made, and written back as the command that reproduces them."""

from __future__ import annotations

from pathlib import Path

import pytest

from compare.bench.suite import BenchError, BenchOptions


def test_the_command_names_only_the_options_that_differ_from_the_defaults():
    assert BenchOptions().command() == "tpik-compare bench"
    options = BenchOptions(
        only="solvers", methods=("tpik", "mink"), json_out=Path("out dir/b.json"), max_candidates=-1, rounds=2
    )
    assert options.command() == (
        "tpik-compare bench --only solvers --methods tpik --methods mink --json 'out dir/b.json'"
        " --max-candidates -1 --rounds 2"
    )


@pytest.mark.parametrize(
    "changes, option",
    [
        ({"only": "nothing"}, "--only"),
        ({"repeats": 0}, "--repeats"),
        ({"max_candidates": 13}, "--max-candidates"),
        ({"rounds": 0}, "--rounds"),
        ({"tolerance": float("nan")}, "--tolerance"),
        ({"backends": ("hqp-daqp", "mink")}, "--backends"),
        ({"export_method": "tpik"}, "--export-method"),
        ({"methods": ()}, "--methods"),
        ({"only": "loop"}, "--only"),
    ],
)
def test_an_option_out_of_range_is_refused_naming_it(changes, option):
    with pytest.raises(BenchError, match=option):
        BenchOptions(**changes)


def test_the_cli_help_states_the_defaults_of_the_suite():
    """``tpik-compare --help`` imports no bench module, so the help repeats the defaults: they must agree."""
    import typer

    from compare.bench.solvers import DEFAULT_METHODS
    from compare.cli import app

    params = {p.name: p for p in typer.main.get_command(app).commands["bench"].params}  # type: ignore[attr-defined]
    assert " ".join(DEFAULT_METHODS) in params["methods"].help
    assert params["max_candidates"].default == BenchOptions.max_candidates
    assert params["export_method"].default == BenchOptions.export_method

"""``tpik-compare methods``: every accepted method name, each with a line saying what it is."""

from __future__ import annotations

from typer.testing import CliRunner

from compare.cli import app
from compare.methods import available_methods, describe


def test_every_accepted_method_name_is_listed_with_its_description():
    result = CliRunner().invoke(app, ["methods"])
    assert result.exit_code == 0, result.output
    listed = {line.split()[0]: line for line in result.output.splitlines() if line.strip()}
    assert set(listed) == set(available_methods())
    for name, line in listed.items():
        assert describe(name), name
        assert line.rstrip().endswith(describe(name))


def test_the_mink_peers_are_described_as_what_they_are():
    """The custom set-task limit and return task are named; mink-hard is the hard-row variant of it."""
    mink, hard = describe("mink"), describe("mink-hard")
    assert "custom mink Limit" in mink and "custom weighted Task" in mink and "not a mink idiom" in mink
    assert "hard return-rate rows" in hard and "strict" not in hard
    assert describe("hqp-daqp").endswith("backend daqp")
    assert "'gain-cap'" in describe("tpik-no-gain-cap")
    assert describe("no-such-method") == ""

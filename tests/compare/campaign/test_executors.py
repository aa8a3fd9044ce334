"""Executors: a Ray worker's run is written into the sweep next to the methods the run already had."""

from __future__ import annotations

from pathlib import Path

from compare.analysis.results import finished_methods, load_summary
from compare.campaign.executors import pack, unpack
from tests.compare.analysis.test_results import _add, _writer


def _packed(tmp: Path, method: str) -> dict[str, bytes]:
    """The files a worker sends back for ``method`` (a run in a temporary directory)."""
    with _writer(tmp, [method]) as w:
        _add(w, method)
    return pack(tmp)


def test_unpack_merges_the_new_method_and_keeps_the_old_one_untouched(tmp_path):
    run_dir = tmp_path / "runs" / "00000"
    with _writer(run_dir, ["tpik"]) as w:
        table = _add(w, "tpik")
    kept = (table.read_bytes(), load_summary(run_dir)["methods"]["tpik"], (run_dir / "config.toml").read_bytes())
    unpack(_packed(tmp_path / "worker", "hqp-daqp"), run_dir)
    summary = load_summary(run_dir)
    assert set(summary["methods"]) == {"tpik", "hqp-daqp"} and finished_methods(run_dir) == {"tpik", "hqp-daqp"}
    assert (table.read_bytes(), summary["methods"]["tpik"], (run_dir / "config.toml").read_bytes()) == kept


def test_unpack_with_overwrite_replaces_an_unreadable_run(tmp_path):
    run_dir = tmp_path / "runs" / "00000"
    run_dir.mkdir(parents=True)
    (run_dir / "summary.json").write_text('{"methods": ')
    unpack(_packed(tmp_path / "worker", "mink"), run_dir, overwrite=True)
    assert finished_methods(run_dir) == {"mink"}
    assert not (run_dir / ".tpik-compare.lock").exists()  # the worker's lock file is not copied

"""Atomic writes: a process killed (or failing) between writing and renaming leaves the old file."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import compare.analysis.atomic_files as atomic
from compare.analysis.atomic_files import (
    FAULT_ENV,
    atomic_write,
    is_temporary,
    remove_stale_temporaries,
    write_json_atomic,
    write_text_atomic,
)

ROOT = Path(__file__).resolve().parents[3]

_WRITER = """
import sys
import numpy as np, pandas as pd
from pathlib import Path
from compare.analysis.atomic_files import write_json_atomic, atomic_write
out = Path(sys.argv[1])
for k in range(1, 4):
    write_json_atomic(out / "summary.json", {"version": k})
    frame = pd.DataFrame({"t": np.arange(1000 * k, dtype=float)})
    atomic_write(out / "steps.parquet", lambda tmp: frame.to_parquet(tmp, index=False))
"""


def _run_writer(out: Path, fault: str | None) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    env.pop(FAULT_ENV, None)
    if fault is not None:
        env[FAULT_ENV] = fault
    return subprocess.run(
        [sys.executable, "-c", _WRITER, str(out)],
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
        start_new_session=True,  # the hook kills its own process group, not pytest's
    )


def test_an_exception_before_the_rename_leaves_the_old_file_and_no_temporary(tmp_path, monkeypatch):
    target = tmp_path / "summary.json"
    write_json_atomic(target, {"version": 1})

    def fail(tmp: Path, final: Path) -> None:
        assert tmp.parent == final.parent and json.loads(tmp.read_text()) == {"version": 2}  # fully written
        raise OSError("disk full")

    monkeypatch.setattr(atomic, "before_replace", fail)
    with pytest.raises(OSError, match="disk full"):
        write_json_atomic(target, {"version": 2})
    assert json.loads(target.read_text()) == {"version": 1}
    assert [p.name for p in tmp_path.iterdir()] == ["summary.json"]


def test_a_failing_writer_leaves_the_old_file(tmp_path):
    target = tmp_path / "report.md"
    write_text_atomic(target, "old\n")

    def half(tmp: Path) -> None:
        tmp.write_text("ne")
        raise ValueError("encoder failed")

    with pytest.raises(ValueError, match="encoder failed"):
        atomic_write(target, half)
    assert target.read_text() == "old\n" and len(list(tmp_path.iterdir())) == 1


@pytest.mark.parametrize("nth", [1, 2, 5])
def test_a_process_killed_mid_write_leaves_the_old_or_the_new_file(tmp_path, nth):
    """SIGKILL after the n-th temporary file is complete, before its rename (the fault hook)."""
    done = _run_writer(tmp_path, f"*@{nth}")
    assert done.returncode == -9, done.stderr  # killed, not finished
    # Writes 1..nth-1 were renamed; write nth (the killed one) never replaced its file.
    written = nth - 1
    versions = {"summary.json": (written + 1) // 2, "steps.parquet": written // 2}
    summary = tmp_path / "summary.json"
    if versions["summary.json"]:
        assert json.loads(summary.read_text()) == {"version": versions["summary.json"]}
    else:
        assert not summary.exists()
    steps = tmp_path / "steps.parquet"
    if versions["steps.parquet"]:
        assert len(pd.read_parquet(steps)) == 1000 * versions["steps.parquet"]
    else:
        assert not steps.exists()
    stray = [p for p in tmp_path.iterdir() if is_temporary(p)]
    assert len(stray) == 1  # the killed write's temporary file, complete but never renamed
    assert remove_stale_temporaries(tmp_path) == 1 and not any(is_temporary(p) for p in tmp_path.iterdir())


def test_the_fault_hook_only_counts_matching_file_names(tmp_path):
    done = _run_writer(tmp_path, "steps.parquet@2")
    assert done.returncode == -9
    assert json.loads((tmp_path / "summary.json").read_text()) == {"version": 2}
    assert len(pd.read_parquet(tmp_path / "steps.parquet")) == 1000


def test_without_the_hook_every_write_lands(tmp_path):
    done = _run_writer(tmp_path, None)
    assert done.returncode == 0, done.stderr
    assert json.loads((tmp_path / "summary.json").read_text()) == {"version": 3}
    assert np.array_equal(pd.read_parquet(tmp_path / "steps.parquet")["t"], np.arange(3000.0))
    assert not any(is_temporary(p) for p in tmp_path.iterdir())


def test_written_files_get_the_mode_open_would_give_them(tmp_path):
    write_text_atomic(tmp_path / "a.txt", "x")
    (tmp_path / "b.txt").write_text("x")
    assert (tmp_path / "a.txt").stat().st_mode == (tmp_path / "b.txt").stat().st_mode

"""Numba's cache is keyed by the content of every kernel file: a changed callee never runs stale."""

from __future__ import annotations

import re
from pathlib import Path

import numba

from robots import kernel_cache
from robots.kernel_cache import KERNEL_FILES, ROOT, cache_dir, kernel_hash


def test_every_file_with_a_cached_kernel_is_hashed():
    found = {
        str(p.relative_to(ROOT))
        for package in ("robots", "tpik", "qp_baseline", "compare")
        for p in (ROOT / package).rglob("*.py")
        if re.search(r"(njit|jit)\([^)]*cache\s*=\s*True", p.read_text(encoding="utf-8"))
    }
    assert found == set(KERNEL_FILES)


def test_a_changed_kernel_file_moves_the_cache(tmp_path: Path):
    files = ("a/kernel.py", "b/caller.py")
    for name in files:
        (tmp_path / name).parent.mkdir(parents=True)
        (tmp_path / name).write_text("x = 1\n", encoding="utf-8")
    before = kernel_hash(tmp_path, files)
    assert kernel_hash(tmp_path, files) == before  # deterministic
    (tmp_path / "a/kernel.py").write_text("x = 2\n", encoding="utf-8")  # the callee only
    assert kernel_hash(tmp_path, files) != before


def test_the_project_uses_its_keyed_directory_unless_the_user_chose_one(monkeypatch, tmp_path: Path):
    monkeypatch.delenv("NUMBA_CACHE_DIR", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    monkeypatch.setattr(numba.config, "CACHE_DIR", numba.config.CACHE_DIR)  # restored afterwards
    path = kernel_cache.use_kernel_cache()
    assert path == cache_dir() and path.is_dir() and numba.config.CACHE_DIR == str(path)
    assert path.name == kernel_hash() and path.parent == tmp_path / "tpik-compare" / "numba"
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "mine"))
    assert kernel_cache.use_kernel_cache() is None

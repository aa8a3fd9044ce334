"""Numba's on-disk cache, one directory per content of the project's compiled kernels.

Numba keys a cached function by the timestamp and size of its own file only. A kernel that
calls a kernel of another file (TPIK's step calls the shared task evaluation, which calls the
chain's frames) would keep its stale machine code after the callee's file changes, e.g. after a
``git checkout``, and silently run the old callee. Here the cache directory is named by a hash of
every file that holds a cached kernel (:data:`KERNEL_FILES`): a change in any of them compiles all
kernels afresh once. A ``NUMBA_CACHE_DIR`` set by the user is left as it is.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

import numba

ROOT = Path(__file__).resolve().parents[1]
"""The directory holding the packages ``robots``, ``tpik``, ``qp_baseline`` and ``compare``."""

KERNEL_FILES = (
    "robots/kinematics.py",
    "tpik/cascade.py",
    "tpik/dls.py",
    "tpik/evaluation.py",
    "tpik/step_rows.py",
    "qp_baseline/cascade_kernels.py",
    "qp_baseline/certificate_dense.py",
    "qp_baseline/set_rows.py",
    "compare/loop/_sigma_kernel.py",
    "compare/loop/joint_drive.py",
    "compare/loop/numpy_dot.py",
    "compare/analysis/iso15066.py",
    "compare/sensing/_frame_kernels.py",
    "compare/sensing/_fusion_kernel.py",
    "compare/sensing/_kernels.py",
    "compare/sensing/ground_truth.py",
)
"""Every file with a ``cache=True`` kernel (tests/robots/test_kernel_cache.py keeps it complete)."""


def kernel_hash(root: Path = ROOT, files: tuple[str, ...] = KERNEL_FILES) -> str:
    """SHA-256 (first 16 hex digits) of the kernel files' contents and of numba's version."""
    digest = hashlib.sha256(numba.__version__.encode())
    for name in files:
        path = root / name
        digest.update(name.encode())
        digest.update(path.read_bytes() if path.is_file() else b"<absent>")
    return digest.hexdigest()[:16]


def cache_dir(root: Path = ROOT) -> Path:
    """``$XDG_CACHE_HOME/tpik-compare/numba/<kernel_hash>`` (``~/.cache`` by default)."""
    base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return base / "tpik-compare" / "numba" / kernel_hash(root)


def use_kernel_cache() -> Path | None:
    """Point numba's cache at :func:`cache_dir`; call before any kernel is decorated.

    Returns:
        The directory, or None (numba's default) when the user set ``NUMBA_CACHE_DIR`` or the
        directory cannot be created.
    """
    if os.environ.get("NUMBA_CACHE_DIR"):
        return None
    try:
        path = cache_dir()
        path.mkdir(parents=True, exist_ok=True)
    except OSError:
        return None
    numba.config.CACHE_DIR = str(path)  # type: ignore[attr-defined]  # set from the environment at import
    return path

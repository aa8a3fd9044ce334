"""Atomic file writes: a killed process leaves the old file or the new one, never half of one.

Every result file (``summary.json``, per-step tables, sweep summaries, manifests, reports,
plots) is written through :func:`atomic_write`:

1. the content goes to a temporary file ``.<name>.<random>.tmp`` in the *same* directory (a
   rename is atomic only within one file system);
2. the temporary file is flushed and ``fsync``-ed (its bytes are on disk before it gets the name);
3. :func:`os.replace` gives it the final name (atomic on POSIX: readers see the old or the new
   file), then the directory is ``fsync``-ed (best effort) so that the rename itself survives a
   power cut.

An exception between 1 and 3 removes the temporary file and leaves the old file as it was. A
process killed there (``SIGKILL``, OOM killer, power cut) leaves a stray temporary file, which
no reader looks at; :func:`remove_stale_temporaries` cleans a directory of them.

Fault hook (tests only): the environment variable :data:`FAULT_ENV` =
``"<pattern>@<n>"`` (``fnmatch`` pattern on the file name, ``n`` ≥ 1) kills the whole process
group with ``SIGKILL`` at the ``n``-th atomic write of a matching file *in this process*, after
step 2 and before step 3 (``"*@3"``: the third write of any file). A test can also set
:data:`before_replace` to a callable ``(temporary, final) -> None`` (e.g. one that raises).
"""

from __future__ import annotations

import contextlib
import fnmatch
import json
import os
import signal
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

FAULT_ENV = "TPIK_COMPARE_WRITE_FAULT"
"""Environment variable of the kill-before-rename fault hook (module docstring)."""

TEMP_SUFFIX = ".tmp"

before_replace: Callable[[Path, Path], None] | None = None
"""Called with (temporary, final path) just before the rename; None = no hook (tests set it)."""

_fault_count = 0  # matching atomic writes so far in this process (FAULT_ENV)
_UMASK = os.umask(0)
os.umask(_UMASK)  # read once at import: files get the mode open() would give them


def _env_fault(final: Path) -> None:
    """The :data:`FAULT_ENV` hook: SIGKILL the process group at the configured write."""
    spec = os.environ.get(FAULT_ENV)
    if not spec:
        return
    pattern, _, nth = spec.rpartition("@")
    if not fnmatch.fnmatch(final.name, pattern or "*"):
        return
    global _fault_count
    _fault_count += 1
    if _fault_count == int(nth):
        with contextlib.suppress(OSError):
            os.killpg(os.getpgid(0), signal.SIGKILL)
        os.kill(os.getpid(), signal.SIGKILL)


def _fsync_directory(directory: Path) -> None:
    """Make a rename in ``directory`` durable (best effort: not every file system allows it)."""
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def atomic_write(path: Path, write: Callable[[Path], object]) -> None:
    """Write ``path`` atomically: ``write(temporary_path)`` fills a temporary file, then rename.

    Args:
        path: Final file (its directory must exist).
        write: Writes the whole content to the path it is given (e.g.
            ``lambda p: frame.to_parquet(p)``); the file exists (empty) when it is called.

    Raises:
        Whatever ``write`` raises, or an :class:`OSError` of the file system; the old ``path``
        is then untouched and the temporary file removed.
    """
    path = Path(path)
    fd, name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=TEMP_SUFFIX, dir=path.parent)
    os.close(fd)
    tmp = Path(name)
    try:
        write(tmp)
        with open(tmp, "rb+") as fh:
            os.fsync(fh.fileno())
        os.chmod(tmp, 0o666 & ~_UMASK)  # mkstemp creates 0600; open() would honour the umask
        _env_fault(path)
        if before_replace is not None:
            before_replace(tmp, path)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    _fsync_directory(path.parent)


def write_text_atomic(path: Path, text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` atomically."""
    atomic_write(path, lambda tmp: tmp.write_text(text, encoding="utf-8"))


def write_bytes_atomic(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically."""
    atomic_write(path, lambda tmp: tmp.write_bytes(data))


def write_json_atomic(path: Path, data: Any) -> None:
    """Write ``data`` as indented JSON to ``path`` atomically.

    NaN/inf are refused (encode them as ``None`` first, see
    :func:`compare.analysis.metrics.to_jsonable`): the ``ValueError`` comes before any file is
    touched.
    """
    text = json.dumps(data, indent=2, allow_nan=False) + "\n"
    write_text_atomic(path, text)


def is_temporary(path: Path) -> bool:
    """Whether ``path`` is a temporary file of :func:`atomic_write` (``.<name>.<random>.tmp``)."""
    return path.name.startswith(".") and path.name.endswith(TEMP_SUFFIX)


def remove_stale_temporaries(directory: Path) -> int:
    """Remove the temporary files a killed writer left in ``directory``; returns how many."""
    removed = 0
    if not Path(directory).is_dir():
        return 0
    for p in Path(directory).iterdir():
        if p.is_file() and is_temporary(p):
            with contextlib.suppress(OSError):
                p.unlink()
                removed += 1
    return removed

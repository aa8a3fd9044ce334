"""Versions of the project, of every solver package and of the machine: stamped on every result (docs/design.md §6)."""

from __future__ import annotations

import functools
import platform
from importlib import metadata

_VERSIONED = (
    "tpik-compare",
    "numpy",
    "mujoco",
    "pin",
    "qpsolvers",
    "mink",
    "daqp",
    "osqp",
    "proxsuite",
    "clarabel",
    "piqp",
    "quadprog",
    "scipy",
)


def versions() -> dict[str, str]:
    """Versions of the project and its numerical dependencies, plus Python and the CPU.

    Read once per process (a sweep worker stamps every run: ~20 ms of package metadata each);
    the caller gets its own dict.
    """
    return dict(_versions())


@functools.cache
def _versions() -> dict[str, str]:
    out = {"python": platform.python_version(), "machine": platform.machine(), "cpu": _cpu_name()}
    for dist in _VERSIONED:
        try:
            out["project" if dist == "tpik-compare" else dist] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            continue
    return out


def _cpu_name() -> str:
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as fh:
            for line in fh:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"

"""Shared fixtures: the Jaco² model and random configurations inside its limits."""

from __future__ import annotations

import os

os.environ.setdefault("MUJOCO_GL", "egl")  # before mujoco is imported (by robots)


def _cpu_has(*flags: str) -> bool:
    try:
        with open("/proc/cpuinfo", encoding="ascii", errors="replace") as fh:
            words = set(next((line for line in fh if line.startswith("flags")), "").split())
    except OSError:
        return False
    return all(f in words for f in flags)


# One BLAS kernel set on every x86-64 machine with AVX2 (before numpy loads OpenBLAS): OpenBLAS
# picks its kernels by CPU, and their round-off differs. The QP methods' velocities are not robust
# to round-off (a 1e-16 change of a row moves HQP's answer by up to 3e-4 rad/s at some states), so
# tests/regression, whose reference was stored with the Haswell kernels, holds to 1e-9 rad/s only
# with the same kernels (with OPENBLAS_CORETYPE=Prescott four methods fail it).
if _cpu_has("avx2", "fma"):
    os.environ.setdefault("OPENBLAS_CORETYPE", "Haswell")

import numpy as np  # noqa: E402
import pytest  # noqa: E402

import robots  # noqa: E402

REALTIME_ALONE = "pytest -m realtime -n 0"
_REALTIME_LEFT_OUT = pytest.StashKey[bool]()


def _parallel(config: pytest.Config) -> bool:
    """Whether this is an xdist run: its controller (``-n`` > 0) or one of its workers."""
    return hasattr(config, "workerinput") or bool(config.getoption("numprocesses", default=None))


def pytest_configure(config: pytest.Config) -> None:
    """Leave the wall-clock ROS tests (marker ``realtime``) out of a parallel run that did not choose by marker.

    Their timing, and so what they check, must not depend on the tests sharing the cores with
    them: ``make test`` runs them alone afterwards (``REALTIME_ALONE``).
    """
    if _parallel(config) and not config.option.markexpr:
        config.option.markexpr = "not realtime"
        config.stash[_REALTIME_LEFT_OUT] = True


def pytest_terminal_summary(terminalreporter: pytest.TerminalReporter, exitstatus: int, config: pytest.Config) -> None:
    if config.stash.get(_REALTIME_LEFT_OUT, False):
        terminalreporter.write_line(
            f"realtime tests left out of this parallel run: run them alone with `{REALTIME_ALONE}`"
        )


@pytest.fixture(scope="session")
def jaco() -> robots.Robot:
    return robots.load("jaco2")


def random_configuration(robot: robots.Robot, rng: np.random.Generator, inset: float = 0.05) -> np.ndarray:
    """Uniform q inside the physical limits (continuous joints in [-π, π])."""
    lo = np.where(np.isfinite(robot.q_lower), robot.q_lower + inset, -np.pi)
    hi = np.where(np.isfinite(robot.q_upper), robot.q_upper - inset, np.pi)
    return rng.uniform(lo, hi)

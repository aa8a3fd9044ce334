"""Shared fixtures: the Jaco² model and random configurations inside its limits."""

from __future__ import annotations

import os

os.environ.setdefault("MUJOCO_GL", "egl")  # before mujoco is imported (by robots)

import numpy as np  # noqa: E402
import pytest  # noqa: E402

import robots  # noqa: E402


@pytest.fixture(scope="session")
def jaco() -> robots.Robot:
    return robots.load("jaco2")


def random_configuration(robot: robots.Robot, rng: np.random.Generator, inset: float = 0.05) -> np.ndarray:
    """Uniform q inside the physical limits (continuous joints in [-π, π])."""
    lo = np.where(np.isfinite(robot.q_lower), robot.q_lower + inset, -np.pi)
    hi = np.where(np.isfinite(robot.q_upper), robot.q_upper - inset, np.pi)
    return rng.uniform(lo, hi)

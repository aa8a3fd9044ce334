"""Validation helpers shared by the task classes."""

from __future__ import annotations

import math

import numpy as np

from tpik.exceptions import TaskDefinitionError


def as_finite_vector(task: str, label: str, value: object, size: int) -> np.ndarray:
    """Return a float copy of ``value`` with shape (size,), or raise naming task and label."""
    arr = np.array(value, dtype=float).reshape(-1)
    if arr.shape != (size,):
        raise TaskDefinitionError(f"task '{task}': {label} must have {size} entries, got {arr.shape[0]}")
    # A finite sum is the cheap test (µs matter at 100 Hz); the exact one only when it fails.
    if not math.isfinite(sum(arr.tolist())) and not np.all(np.isfinite(arr)):
        raise TaskDefinitionError(f"task '{task}': {label} must be finite, got {arr.tolist()}")
    return arr


def as_rotation(task: str, value: object) -> np.ndarray:
    """Return a float copy of a 3×3 rotation matrix, or raise if it is not one (1e-6)."""
    rot = np.array(value, dtype=float)
    if rot.shape != (3, 3) or not np.all(np.isfinite(rot)):
        raise TaskDefinitionError(f"task '{task}': target rotation must be a finite 3x3 matrix")
    if not np.allclose(rot @ rot.T, np.eye(3), atol=1e-6) or np.linalg.det(rot) < 0.0:
        raise TaskDefinitionError(f"task '{task}': target is not a rotation matrix")
    return rot

"""Hand-built scenes of the witness, verdict and loop tests: the Jaco² at case 2's start, a scripted person."""

from __future__ import annotations

from typing import Any

import numpy as np

from compare.config import Config, parse_config

Q0 = (4.9, 3.78, 3.392, 1.124, 3.156, 2.03, 0.0)
"""Case 2's start pose: EE at (0.10, 0.20, 0.45) m, joints 2/4/6 mid-range [rad]."""
CPS = ("link_4", "link_6", "link_7")
"""The control points of the obstacle tasks."""


def levels(walls: bool = True) -> list[dict[str, Any]]:
    """Joint limits 2, 4, 6; the EE's box of walls (optional); the obstacle tasks (0.35 m); the EE position."""
    out: list[dict[str, Any]] = [
        {"name": "joint_limits", "tasks": [{"type": "joint_limit", "joints": [2, 4, 6], "safety_margin": 0.1}]}
    ]
    if walls:
        box = {"type": "wall_box", "frame": "end_effector", "lower": [-0.5, -0.5, 0.2], "upper": [0.5, 0.5, 0.9]}
        out.append({"name": "walls", "tasks": [box]})
    obstacle = {"type": "obstacle_distance", "frames": list(CPS), "safety_distance": 0.35, "physical_distance": 0.1}
    out += [
        {"name": "obstacles", "tasks": [obstacle]},
        {"name": "operational", "tasks": [{"type": "position", "frame": "end_effector"}]},
    ]
    return out


def scene(
    keyframes: list[dict[str, Any]],
    duration_s: float,
    simulation: str = "kinematic",
    walls: bool = True,
    oracle: dict[str, Any] | None = None,
    kind: str = "scripted",
) -> Config:
    """The arm held at :data:`Q0` (no waypoint) with a person on ``keyframes``, geometric sensing, tpik."""
    return parse_config(
        {
            "scenario": {
                "name": "scene",
                "kind": kind,
                "duration_s": duration_s,
                "sensing": "geometric",
                "simulation": simulation,
                "start_q": list(Q0),
            },
            "waypoints": {"positions": []},
            "person": {"keyframes": keyframes},
            "levels": levels(walls),
            "methods": {"names": ["tpik"]},
            "oracle": {"enabled": True} | (oracle or {}),
        }
    )


def control_point(robot: Any, name: str = "link_7") -> np.ndarray:
    """A control point's position at :data:`Q0` [m]."""
    return np.array(robot.kinematics(np.array(Q0)).frame_position(name))

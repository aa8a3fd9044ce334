r"""A new set-based task in one file: keep the elbow above a height (``docs/extending.md``).

.. math:: \sigma = e_z^T p_{elbow}(q),\quad J = e_z^T J_{pos,elbow}(q),\quad
    \sigma \ge \sigma_{s,l} = h_{min}

Import it (``[extensions] modules = ["elbow_height.py"]`` in a scenario TOML) and
``type = "elbow_height"`` is a task type of every method: TPIK inserts it when σ reaches
:math:`h_{min} + \varepsilon` (paper eq. 7), HQP bounds σ̇, mink gets it as a limit; its
violations are counted under ``"elbow_height"`` in ``summary.json``.
"""

from __future__ import annotations

import math

import numpy as np

import tpik
from robots import Kinematics, Robot
from tpik.tasks import SetTask, Task, TaskKey, TaskSpec, Thresholds


class ElbowHeightTask(SetTask):
    """Height of a frame origin above the table (base z) [m], kept above a minimum.

    Args:
        name: Task name.
        frame: The elbow frame (``link_4`` on the Jaco²: the origin of joint 4).
        thresholds: Thresholds on the height [m] (lower side only).
        gain: K [1/s].
    """

    default_group = "elbow_height"  # its own line in summary.json and the reports

    def __init__(self, name: str, frame: str, thresholds: Thresholds, gain: float = 1.0) -> None:
        super().__init__(name, thresholds, gain)
        self.frame = frame

    def compute_value_and_jacobian(self, kin: Kinematics) -> tuple[float, np.ndarray]:
        """σ = z of the frame origin, J = the z row of its position Jacobian, shape (1, n)."""
        return float(kin.frame_position(self.frame)[2]), kin.position_jacobian(self.frame)[2:3]


KEYS = (
    TaskKey("frame", "elbow frame", "link_4"),
    TaskKey("min_height_m", "σ_{s,l}: lowest height held", 0.5, "m"),
    TaskKey("physical_margin_m", "σ_m = min_height_m − this: where the elbow would hit", 0.05, "m"),
    TaskKey("activation_margin_m", "ε: activation this far above min_height_m", 0.03, "m"),
    TaskKey("gain", "closed-loop gain K", 1.0, "1/s"),
    TaskKey("name", "task name", "elbow_height"),
)


def build(spec: TaskSpec, robot: Robot) -> list[Task]:
    """One :class:`ElbowHeightTask` from a description entry (every error names the key)."""
    low = spec.number("min_height_m")
    th = Thresholds(
        low - spec.number("physical_margin_m", positive=True),
        low,
        math.inf,
        math.inf,
        spec.number("activation_margin_m", positive=True),
    )
    return [ElbowHeightTask(spec.text("name"), spec.frame("frame"), th, spec.number("gain", positive=True))]


tpik.register_task("elbow_height", build, keys=KEYS, example={"min_height_m": 0.5}, summary="elbow height [m]")

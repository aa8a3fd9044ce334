"""``[prediction]`` in the closed loop: what the obstacle tasks receive, what is recorded, what it changes.

A person walks straight at link 7 at 1 m/s and reaches for it. The estimate must see the
approach from the sensing stream (closing speed near the walking speed while the person walks),
the truth must too, and both must keep the arm farther from the person than the reactive tasks
do. With ``mode = "off"`` nothing of the run changes (no prediction columns).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from compare.config import parse_config
from compare.run import run_method
from tests.compare.scenes import CPS, control_point, scene


def _config(jaco, prediction: dict | None):
    p7 = control_point(jaco)
    start = [float(p7[0]), float(p7[1] + 1.8)]
    near = [float(p7[0]), float(p7[1] + 0.6)]
    frames = [
        {"t": 0.0, "position": start, "yaw": -math.pi / 2},
        {"t": 1.2, "position": near, "yaw": -math.pi / 2, "right_hand": (p7 + [0.0, 0.15, 0.0]).tolist()},
        {"t": 3.0, "position": near, "yaw": -math.pi / 2, "right_hand": (p7 + [0.0, 0.15, 0.0]).tolist()},
    ]
    data = scene(frames, 3.0, simulation="dynamic", walls=False).model_dump()
    data["oracle"]["enabled"] = False
    data["sensor"]["rho_m"] = 1.0
    if prediction is not None:
        data["prediction"] = prediction
    return parse_config(data)


@pytest.fixture(scope="module")
def runs(jaco):
    """tpik on the scene without prediction, with the estimate and with the truth."""
    out = {}
    for name, prediction in (("off", None), ("estimated", {"mode": "estimated"}), ("truth", {"mode": "truth"})):
        out[name] = run_method(_config(jaco, prediction), "tpik", jaco)["steps"]
    return out


def test_off_records_no_prediction(runs):
    assert not any(c.startswith(("dist_pred:", "closing_pred:")) for c in runs["off"].columns)
    for name in ("estimated", "truth"):
        assert {f"closing_pred:{cp}" for cp in CPS} <= set(runs[name].columns)


def _closing_while_walking(steps) -> float:
    """Median predicted closing speed of link 7 while the person walks in (0.6–1.1 s) [m/s]."""
    t = steps["t"].to_numpy()
    walking = (t > 0.6) & (t < 1.1) & np.isfinite(steps["dist_pred:link_7"].to_numpy())
    assert walking.sum() > 20
    return float(np.median(steps["closing_pred:link_7"].to_numpy()[walking]))


def test_the_approach_is_seen(runs):
    """The hand closes in at ~1.4 m/s (walk and reach): the estimate agrees with the truth to 0.25 m/s."""
    truth = _closing_while_walking(runs["truth"])
    assert truth > 1.0
    assert _closing_while_walking(runs["estimated"]) == pytest.approx(truth, abs=0.25)


@pytest.mark.parametrize("name", ["estimated", "truth"])
def test_prediction_keeps_the_arm_farther(runs, name):
    """The smallest true distance is larger by at least 3 cm than with the reactive tasks alone."""

    def closest(steps):
        return float(np.nanmin(steps[[f"dist_true:{cp}" for cp in CPS]].to_numpy()))

    assert closest(runs[name]) > closest(runs["off"]) + 0.03


def test_the_prediction_reaches_every_method(jaco):
    """The same scene with hqp-daqp and mink: the tasks receive the same prediction, the arm stays farther."""
    for method in ("hqp-daqp", "mink"):
        off = run_method(_config(jaco, None), method, jaco)["steps"]
        on = run_method(_config(jaco, {"mode": "estimated"}), method, jaco)["steps"]
        cols = [f"dist_true:{cp}" for cp in CPS]
        assert float(np.nanmin(on[cols].to_numpy())) > float(np.nanmin(off[cols].to_numpy())) + 0.03, method

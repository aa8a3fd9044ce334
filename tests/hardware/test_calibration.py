"""Calibration check: the arm model rendered from the configured camera vs a "live" depth frame (no ROS).

The live frame is the work cell's camera rendering the whole scene with Kinect-like noise; the
configured pose is that camera's pose, or that pose moved by a known error.
"""

from __future__ import annotations

import dataclasses
import os

import mujoco
import numpy as np
import pytest

from compare.hardware.calibration import ArmRenderer, alignment_residual, set_mujoco_camera
from compare.hardware.run import calibration_problem
from compare.sensing.camera import DepthNoise, camera_model_from_mujoco

pytestmark = [
    pytest.mark.rendering,
    pytest.mark.skipif(
        mujoco.GLContext.__module__.endswith("glfw") and not os.environ.get("DISPLAY"),
        reason="offscreen rendering needs MUJOCO_GL=egl before mujoco is imported (the Makefile exports it)",
    ),
]

LIMIT_M = 0.02


@pytest.fixture(scope="module")
def live(jaco):
    """A noisy depth frame of the work cell with the arm at home, and the camera that took it."""
    from compare.sensing.renderer import DepthCamera
    from compare.sensing.scene import load_workcell, make_data

    model = load_workcell()
    # Kinect v2-like: ~1.5 mm per metre of depth, a few per cent of pixels without return.
    with DepthCamera(model, noise=DepthNoise(std_m=0.0015, proportional=True, dropout=0.02), seed=3) as cam:
        frame = cam.render(make_data(model, jaco.home))
    return frame


def _moved(camera, offset_optical_m):
    T = camera.transform_base_to_camera.copy()
    T[:3, 3] += T[:3, :3] @ np.asarray(offset_optical_m, dtype=float)
    return dataclasses.replace(camera, transform_base_to_camera=T)


def _residual(camera, q, measured):
    renderer = ArmRenderer(camera)
    try:
        return alignment_residual(measured, renderer.render(q))
    finally:
        renderer.close()


def test_the_configured_camera_is_what_mujoco_renders_from():
    from compare.sensing.scene import load_workcell

    model = load_workcell()
    truth = camera_model_from_mujoco(model)
    wanted = dataclasses.replace(
        _moved(truth, [0.1, -0.05, 0.2]), fx=380.0, fy=377.0, cx=250.5, cy=210.25, width=512, height=424
    )
    set_mujoco_camera(model, "depth_camera", wanted)
    got = camera_model_from_mujoco(model)
    for name in ("width", "height", "fx", "fy", "cx", "cy"):
        assert getattr(got, name) == pytest.approx(getattr(wanted, name), abs=1e-6), name
    np.testing.assert_allclose(got.transform_base_to_camera, wanted.transform_base_to_camera, atol=1e-9)


def test_a_correct_camera_pose_leaves_only_the_sensor_noise(live, jaco):
    r = _residual(live.camera, jaco.home, live.depth_m)
    print(f"\ncorrect pose: {r.describe()}")
    assert r.conclusive and r.valid_pixels > 1000
    assert r.residual_m < 0.006
    assert calibration_problem(r, LIMIT_M) is None


@pytest.mark.parametrize(
    "offset",
    [(0.052, 0.0, 0.0), (-0.05, 0.0, 0.0), (0.0, 0.05, 0.0), (0.0, -0.05, 0.0), (0.0, 0.0, 0.05), (0.0, 0.0, -0.05)],
    ids=["rgb-for-ir+x", "-x", "+y", "-y", "+z", "-z"],
)
def test_a_5_cm_camera_pose_error_is_detected_and_refused(live, jaco, offset):
    r = _residual(_moved(live.camera, offset), jaco.home, live.depth_m)
    print(f"\noffset {offset}: {r.describe()}")
    assert r.residual_m > LIMIT_M
    problem = calibration_problem(r, LIMIT_M)
    assert problem is not None and problem.startswith("camera calibration off") and "\n" not in problem


def test_a_1_cm_error_passes_and_a_disabled_check_never_refuses(live, jaco):
    r = _residual(_moved(live.camera, (0.0, 0.0, 0.01)), jaco.home, live.depth_m)
    assert r.residual_m < LIMIT_M
    far = _residual(_moved(live.camera, (0.0, 0.0, 0.05)), jaco.home, live.depth_m)
    assert calibration_problem(far, 0.0) is None


def test_an_arm_hidden_from_the_camera_makes_the_check_inconclusive(live, jaco):
    blank = np.zeros_like(live.depth_m)
    r = _residual(live.camera, jaco.home, blank)
    assert not r.conclusive
    assert "inconclusive" in calibration_problem(r, LIMIT_M)

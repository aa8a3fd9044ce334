"""Cameras from ``[[sensor.cameras]]`` in the MuJoCo scene: pose, intrinsics and range as configured."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from compare.config import CameraConfig, ConfigError, load_config
from compare.sensing import (
    STATIC_GROUP,
    DepthCamera,
    SensingError,
    camera_model_from_mujoco,
    load_rig_workcell,
    load_workcell,
    make_data,
    project,
)
from compare.sensing.rig import KINECT_V2, scene_camera_names
from tests.compare.sensing.test_fusion import CONFIGS

SECOND = CameraConfig(name="cam_b", position_m=(0.3, 2.0, 1.7), look_at_m=(0.0, 0.1, 0.4))


def test_no_cameras_is_the_scene_as_the_mjcf_gives_it():
    plain, rig = load_workcell(), load_rig_workcell("jaco2", [])
    a, b = camera_model_from_mujoco(plain), camera_model_from_mujoco(rig)
    np.testing.assert_array_equal(a.transform_base_to_camera, b.transform_base_to_camera)
    assert (a.fx, a.fy, a.cx, a.cy, a.min_range_m, a.max_range_m) == (b.fx, b.fy, b.cx, b.cy, 0.5, 4.5)
    assert scene_camera_names() == ["depth_camera"]


def test_an_added_camera_looks_at_its_target_with_kinect_intrinsics():
    model = load_rig_workcell("jaco2", [CameraConfig(name="depth_camera"), SECOND])
    cam = camera_model_from_mujoco(model, "cam_b")
    np.testing.assert_allclose(cam.transform_base_to_camera[:3, 3], SECOND.position_m, atol=1e-9)
    uv, depth = project(cam, np.array([SECOND.look_at_m]))
    np.testing.assert_allclose(uv[0], [KINECT_V2.principal_px[0], KINECT_V2.principal_px[1]], atol=1e-6)
    assert depth[0] == pytest.approx(np.linalg.norm(np.subtract(SECOND.look_at_m, SECOND.position_m)))
    assert abs(cam.transform_base_to_camera[2, 0]) < 1e-9  # image x horizontal
    assert (cam.width, cam.height, cam.fx, cam.fy) == (512, 424, 365.5, 365.5)
    assert (cam.min_range_m, cam.max_range_m) == KINECT_V2.range_m


@pytest.mark.rendering
def test_the_added_camera_renders_what_mujoco_ray_casting_sees():
    # Independent reference: mj_ray from the optical centre through chosen pixels to the static scene.
    cfg = CameraConfig(
        name="cam_b", position_m=(0.4, 1.6, 1.2), look_at_m=(0.0, 0.0, -0.3), resolution=(320, 240),
        focal_px=(250.0, 260.0), principal_px=(150.0, 130.0), range_m=(0.3, 6.0),
    )  # fmt: skip
    model = load_rig_workcell("jaco2", [cfg])
    data = make_data(model)
    mujoco.mj_camlight(model, data)
    with DepthCamera(model, "cam_b") as camera:
        cam = camera.camera
        assert (cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy) == (320, 240, 250.0, 260.0, 150.0, 130.0)
        assert (cam.min_range_m, cam.max_range_m) == (0.3, 6.0)
        depth = camera.render_static(data)
    groups = np.zeros(6, dtype=np.uint8)
    groups[STATIC_GROUP] = 1
    R, t = cam.transform_base_to_camera[:3, :3], cam.transform_base_to_camera[:3, 3]
    checked = 0
    for u, v in [(10, 230), (150, 130), (300, 200), (40, 120), (160, 235)]:
        ray = R @ np.array([(u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, 1.0])
        geom = np.array([-1], dtype=np.int32)
        dist = mujoco.mj_ray(model, data, t, ray / np.linalg.norm(ray), groups, 1, -1, geom)
        if dist < 0:
            continue
        expected = dist / np.linalg.norm(ray)  # depth along the optical axis
        assert depth[v, u] == pytest.approx(expected, abs=2e-3), (u, v)
        checked += 1
    assert checked >= 4


def test_the_scene_camera_can_be_re_aimed_and_keeps_its_intrinsics():
    moved = CameraConfig(name="depth_camera", position_m=(1.5, -1.5, 1.5), look_at_m=(0.0, 0.0, 0.3))
    cam = camera_model_from_mujoco(load_rig_workcell("jaco2", [moved]))
    original = camera_model_from_mujoco(load_workcell())
    np.testing.assert_allclose(cam.transform_base_to_camera[:3, 3], moved.position_m)
    assert (cam.fx, cam.cx, cam.cy) == (original.fx, original.cx, original.cy)
    uv, _ = project(cam, np.array([moved.look_at_m]))
    np.testing.assert_allclose(uv[0], [cam.cx, cam.cy], atol=1e-6)


def test_a_calibrated_optical_quaternion_gives_that_orientation():
    # Optical frame looking along -z of the world (straight down), image x = world x.
    cfg = CameraConfig(name="top", position_m=(0.0, 0.0, 2.5), quaternion_xyzw=(1.0, 0.0, 0.0, 0.0))
    cam = camera_model_from_mujoco(load_rig_workcell("jaco2", [cfg]), "top")
    np.testing.assert_allclose(cam.transform_base_to_camera[:3, :3], np.diag([1.0, -1.0, -1.0]), atol=1e-12)


def test_a_new_camera_without_pose_is_refused():
    with pytest.raises(SensingError, match="cam_x"):
        load_rig_workcell("jaco2", [CameraConfig(name="cam_x")])
    with pytest.raises(ConfigError, match=r"^sensor\.cameras\[1\]\.position_m: camera 'cam_x'"):
        load_config(CONFIGS / "case1.toml", {"sensor.cameras": [{"name": "depth_camera"}, {"name": "cam_x"}]})


@pytest.mark.parametrize(
    ("cameras", "key"),
    [
        ([{"name": "a", "position_m": [0, 1, 1]}], "sensor.cameras[0]"),
        ([{"name": "a", "position_m": [0, 1, 1], "look_at_m": [0, 1, 1]}], "sensor.cameras[0]"),
        ([{"name": "depth_camera", "rate_hz": 15.0}], "sensor.cameras[0].rate_hz"),
        ([{"name": "depth_camera", "range_m": [2.0, 1.0]}], "sensor.cameras[0]"),
        ([{"name": "depth_camera"}, {"name": "depth_camera"}], "sensor.cameras"),
        ([{"name": "depth_camera", "zoom": 2}], "sensor.cameras[0].zoom"),
    ],
)
def test_bad_camera_entries_name_the_key(cameras, key):
    with pytest.raises(ConfigError, match="^" + key.replace("[", r"\[").replace("]", r"\]").replace(".", r"\.")):
        load_config(CONFIGS / "case1.toml", {"sensor.cameras": cameras})


def test_min_support_above_one_is_refused_with_several_cameras():
    two = [{"name": "depth_camera"}, {"name": "cam_b", "position_m": [0.3, 2.0, 1.7], "look_at_m": [0.0, 0.1, 0.4]}]
    with pytest.raises(ConfigError, match=r"^sensor: .*min_support = 2 needs one camera \(got 2\)"):
        load_config(CONFIGS / "case1.toml", {"sensor.cameras": two, "sensor.min_support": 2})
    config, _ = load_config(CONFIGS / "case1.toml", {"sensor.cameras": two[:1], "sensor.min_support": 2})
    assert config.sensor.min_support == 2
    with pytest.raises(ConfigError, match=r"^sensor\.min_support"):
        load_config(CONFIGS / "case1.toml", {"sensor.min_support": 0})


def test_a_fault_on_a_camera_that_does_not_exist_is_refused():
    with pytest.raises(ConfigError, match=r"^faults\.inject\[0\]\.camera"):
        load_config(CONFIGS / "case1.toml", {"faults.inject": [{"kind": "depth_nan", "camera": 1}]})

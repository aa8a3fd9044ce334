"""The depth camera: intrinsics/extrinsics from the MJCF, projection, rendering conventions, noise."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
from OpenGL import GL

from compare.sensing import (
    DepthCamera,
    DepthNoise,
    SensingError,
    UnknownSceneElement,
    camera_model_from_mujoco,
    deproject,
    load_workcell,
    make_data,
    point_cloud,
    project,
    renderer,
    set_camera_look_at,
    valid_fraction,
)
from compare.sensing.camera import base_to_sensor, sensor_to_base
from compare.sensing.frames import DepthFrame


@pytest.fixture(scope="module")
def model():
    return load_workcell()


@pytest.fixture(scope="module")
def camera(model):
    return camera_model_from_mujoco(model)


def test_intrinsics_are_the_kinect_v2_depth_stream(camera):
    assert (camera.width, camera.height) == (512, 424)
    assert camera.fx == pytest.approx(365.5, abs=1e-3)
    assert camera.fy == pytest.approx(365.5, abs=1e-3)
    assert camera.cx == pytest.approx(255.0, abs=1e-3)
    assert camera.cy == pytest.approx(205.0, abs=1e-3)
    assert (camera.min_range_m, camera.max_range_m) == (0.5, 4.5)


def test_extrinsics_come_from_the_model_and_are_a_rotation(model, camera):
    T = camera.transform_base_to_camera
    np.testing.assert_allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-12)
    assert np.linalg.det(T[:3, :3]) == pytest.approx(1.0)
    np.testing.assert_allclose(T[:3, 3], model.cam_pos[0])
    # optical z looks at the workspace (forward and down), image x is horizontal
    assert T[1, 2] > 0.5 and T[2, 2] < -0.3
    assert abs(T[2, 0]) < 1e-9


def test_workspace_box_is_in_view_and_in_range(camera):
    corners = np.array([[x, y, z] for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (0.0, 1.0)])
    uv, d = project(camera, corners)
    assert np.all((uv[:, 0] >= 0) & (uv[:, 0] <= camera.width - 1))
    assert np.all((uv[:, 1] >= 0) & (uv[:, 1] <= camera.height - 1))
    assert np.all((d > camera.min_range_m) & (d < camera.max_range_m))


def test_pixel_to_point_to_pixel_round_trip_is_exact(camera):
    rng = np.random.default_rng(0)
    uv = np.column_stack([rng.integers(0, camera.width, 500), rng.integers(0, camera.height, 500)]).astype(float)
    depth = rng.uniform(camera.min_range_m, camera.max_range_m, 500)
    points = deproject(camera, uv, depth)
    uv_back, depth_back = project(camera, points)
    np.testing.assert_allclose(uv_back, uv, atol=1e-9)
    np.testing.assert_allclose(depth_back, depth, atol=1e-12)
    np.testing.assert_allclose(sensor_to_base(camera, base_to_sensor(camera, points)), points, atol=1e-12)


def test_paper_formula_for_the_sensor_point(camera):
    # P_s,x = (p_x - c_x) d_p / (f s_x), P_s,y = (p_y - c_y) d_p / (f s_y), P_s,z = d_p (sec. III)
    u, v, d = 400.0, 17.0, 2.25
    p_sensor = base_to_sensor(camera, deproject(camera, [[u, v]], [d])[0])
    np.testing.assert_allclose(p_sensor, [(u - camera.cx) * d / camera.fx, (v - camera.cy) * d / camera.fy, d])


def test_unknown_camera_lists_the_cameras(model):
    with pytest.raises(UnknownSceneElement, match="depth_camera"):
        camera_model_from_mujoco(model, "kinect")


def test_re_aimed_camera_sees_its_target_at_the_principal_point():
    model = load_workcell()
    target = np.array([0.2, 0.1, 0.4])
    set_camera_look_at(model, np.array([1.5, -1.5, 1.2]), target)
    cam = camera_model_from_mujoco(model)
    uv, d = project(cam, target[None])
    np.testing.assert_allclose(uv[0], [cam.cx, cam.cy], atol=1e-9)
    assert d[0] == pytest.approx(np.linalg.norm(target - [1.5, -1.5, 1.2]))
    with pytest.raises(SensingError):
        set_camera_look_at(model, target, target)


def test_noise_model_validates_its_parameters():
    with pytest.raises(SensingError):
        DepthNoise(std_m=-0.1)
    with pytest.raises(SensingError):
        DepthNoise(dropout=1.5)
    assert DepthNoise(0.01, proportional=True).std_at(2.0) == pytest.approx(0.02)
    assert DepthNoise(0.01).std_at(2.0) == pytest.approx(0.01)


@pytest.fixture(scope="module")
def rig(model):
    data = make_data(model)
    cam = DepthCamera(model)
    yield cam, data
    cam.close()


@pytest.mark.rendering
class TestRendering:
    def test_static_scene_depth_is_along_the_optical_axis(self, rig, model):
        # Every valid pixel of the static scene, deprojected with the camera model, lands on the
        # table top (z = 0, |x|, |y| <= 0.6) or the floor (z = -0.75): checks the depth convention
        # (z-depth, not ray length), the intrinsics and the extrinsics together.
        cam, data = rig
        depth = cam.render_static(data)
        frame = DepthFrame(depth, 0.0, cam.camera)
        points, _ = point_cloud(frame)
        on_top = np.abs(points[:, 2]) < 2e-3
        on_floor = np.abs(points[:, 2] + 0.75) < 2e-3
        assert np.mean(on_top | on_floor) > 0.97
        top = points[on_top]
        assert top.shape[0] > 5000
        assert np.all(np.abs(top[:, :2]) <= 0.6 + 5e-3)
        # the table's edges are where the model says (within a pixel footprint at ~2.5 m)
        assert np.max(top[:, 0]) == pytest.approx(0.6, abs=0.01)
        assert np.min(top[:, 0]) == pytest.approx(-0.6, abs=0.01)
        assert np.min(top[:, 1]) == pytest.approx(-0.6, abs=0.01)

    def test_principal_point_offset_sign_matches_the_renderer(self):
        # A large principal offset makes a sign error in cx/cy visible as tilted planes.
        shifted = load_workcell()
        px_to_m = shifted.cam_sensorsize[0] / shifted.cam_resolution[0]
        shifted.cam_intrinsic[0, 2:4] += np.array([25.0, -20.0]) * px_to_m
        cam = DepthCamera(shifted)
        try:
            assert cam.camera.cx == pytest.approx(255.0 - 25.0)
            assert cam.camera.cy == pytest.approx(205.0 + 20.0)
            frame = DepthFrame(cam.render_static(make_data(shifted)), 0.0, cam.camera)
        finally:
            cam.close()
        points, _ = point_cloud(frame)
        top = points[np.abs(points[:, 2]) < 2e-3]
        assert np.mean(np.abs(points[:, 2]) < 2e-3) + np.mean(np.abs(points[:, 2] + 0.75) < 2e-3) > 0.97
        assert np.max(top[:, 0]) == pytest.approx(0.6, abs=0.01)
        assert np.min(top[:, 0]) == pytest.approx(-0.6, abs=0.01)

    def test_matches_mujoco_renderer_and_marks_no_return_as_zero(self, rig, model):
        import mujoco

        cam, data = rig
        depth = cam.render_depth(data)
        with mujoco.Renderer(model, 424, 512) as ref_renderer:
            ref_renderer.enable_depth_rendering()
            ref_renderer.update_scene(data, "depth_camera")
            ref = ref_renderer.render()
        ref[(ref < 0.5) | (ref > 4.5)] = 0.0
        # planes drawn as boxes and our own conversion: same image
        np.testing.assert_allclose(depth, ref, atol=1e-4)
        assert depth.dtype == np.float32
        assert np.all(depth[0] == 0.0)  # top rows look past the floor's 4.5 m: no return
        assert 0.3 < valid_fraction(cam.render(data)) < 0.8

    def test_noise_and_dropout_are_seeded_and_sized(self, model, rig):
        _, data = rig
        clean_cam = DepthCamera(model)
        noisy_a = DepthCamera(model, noise=DepthNoise(0.01, dropout=0.1), seed=7)
        noisy_b = DepthCamera(model, noise=DepthNoise(0.01, dropout=0.1), seed=7)
        try:
            clean = clean_cam.render_depth(data)
            a = noisy_a.render_depth(data)
            b = noisy_b.render_depth(data)
        finally:
            for c in (clean_cam, noisy_a, noisy_b):
                c.close()
        np.testing.assert_array_equal(a, b)
        both = (clean > 0) & (a > 0)
        assert np.std(a[both] - clean[both]) == pytest.approx(0.01, rel=0.05)
        dropped = np.mean(a[clean > 0.6] == 0)
        assert dropped == pytest.approx(0.1, abs=0.01)

    def test_colour_writes_off_leave_the_depth_bit_for_bit(self, model, monkeypatch):
        data = make_data(model)
        data.qpos[:7] = [0.3, 2.9, 0.2, 1.4, -0.5, 3.5, 0.1]  # the arm in view, over the table
        mujoco.mj_kinematics(model, data)
        cam = DepthCamera(model)
        try:
            cam.render_depth(data)  # a camera's first frame differs in the last bits: compare later ones
            off = cam.render_depth(data)
            assert not any(GL.glGetBooleanv(GL.GL_COLOR_WRITEMASK))
            GL.glColorMask(True, True, True, True)
            monkeypatch.setattr(renderer.GL, "glColorMask", lambda *mask: None)  # colour written
            on = cam.render_depth(data)
            assert all(GL.glGetBooleanv(GL.GL_COLOR_WRITEMASK))
        finally:
            cam.close()
        np.testing.assert_array_equal(off, on)
        assert np.count_nonzero(off) > 1000

    def test_closed_camera_refuses_to_render(self, model, rig):
        _, data = rig
        cam = DepthCamera(model)
        cam.close()
        cam.close()
        with pytest.raises(SensingError, match="closed"):
            cam.render(data)

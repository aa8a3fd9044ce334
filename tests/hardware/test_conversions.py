"""Unit conversions at the ROS boundary (no ROS needed)."""

from __future__ import annotations

import math

import numpy as np
import pytest

import robots
from compare.config import HardwareConfig
from compare.hardware.conversions import (
    camera_model_from_info,
    decode_depth,
    deg_s_to_rad_s,
    encode_depth,
    joint_indices,
    rad_s_to_deg_s,
    transform_from_translation_quaternion,
    translation_quaternion_from_transform,
)
from compare.hardware.exceptions import HardwareError


def test_velocity_goes_out_in_degrees_per_second():
    qdot = np.array([math.pi, -math.pi / 2, 0.0, 0.1, 0.0, 0.0, 1.0])
    deg = rad_s_to_deg_s(qdot)
    assert deg[0] == pytest.approx(180.0)
    assert deg[1] == pytest.approx(-90.0)
    np.testing.assert_allclose(deg_s_to_rad_s(deg), qdot)


def test_arm_joints_are_picked_by_name_whatever_the_order():
    names = ["j2s7s300_joint_finger_1", *[f"j2s7s300_joint_{i}" for i in (7, 6, 5, 4, 3, 2, 1)]]
    idx = joint_indices(names, robots.load("jaco2").joint_names)  # hardware.joint_names default
    assert idx.tolist() == [7, 6, 5, 4, 3, 2, 1]


def test_missing_joint_is_named():
    with pytest.raises(HardwareError, match="j2s7s300_joint_7"):
        joint_indices([f"j2s7s300_joint_{i}" for i in range(1, 7)], robots.load("jaco2").joint_names)


@pytest.mark.parametrize("encoding", ["16UC1", "32FC1"])
def test_depth_round_trip(encoding):
    rng = np.random.default_rng(0)
    depth = rng.uniform(0.5, 4.5, (6, 5)).astype(np.float32)
    depth[0, 0] = 0.0
    depth[1, 1] = np.nan
    step, data = encode_depth(depth, encoding)
    out = decode_depth(encoding, 6, 5, step, False, data)
    assert out.dtype == np.float32 and out.shape == (6, 5)
    assert out[0, 0] == 0.0 and out[1, 1] == 0.0
    mask = np.isfinite(depth) & (depth > 0)
    np.testing.assert_allclose(out[mask], depth[mask], atol=6e-4 if encoding == "16UC1" else 1e-7)


def test_depth_16uc1_is_millimetres_and_rows_may_be_padded_big_endian():
    mm = np.array([[1000, 2500], [0, 65535]], dtype=">u2")
    padded = np.zeros((2, 6), dtype=np.uint8)
    padded[:, :4] = mm.view(np.uint8).reshape(2, 4)
    out = decode_depth("16UC1", 2, 2, 6, True, padded.tobytes())
    np.testing.assert_allclose(out, [[1.0, 2.5], [0.0, 65.535]], rtol=1e-6)


def test_bad_depth_messages_are_rejected():
    with pytest.raises(HardwareError, match="rgb8"):
        decode_depth("rgb8", 2, 2, 6, False, bytes(12))
    with pytest.raises(HardwareError, match="too small"):
        decode_depth("16UC1", 2, 2, 4, False, bytes(7))


def test_quaternion_transform_round_trip():
    rng = np.random.default_rng(1)
    for _ in range(20):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        q *= np.sign(q[3])
        t = rng.normal(size=3)
        T = transform_from_translation_quaternion(t, q)
        np.testing.assert_allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-12)
        assert np.linalg.det(T[:3, :3]) == pytest.approx(1.0)
        t2, q2 = translation_quaternion_from_transform(T)
        np.testing.assert_allclose(t2, t, atol=1e-12)
        np.testing.assert_allclose(q2, q, atol=1e-9)


def test_quaternion_is_x_y_z_w():
    # 90° about z: x axis goes to y.
    T = transform_from_translation_quaternion([0, 0, 0], [0.0, 0.0, math.sqrt(0.5), math.sqrt(0.5)])
    np.testing.assert_allclose(T[:3, :3] @ [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], atol=1e-12)


def test_camera_info_gives_the_pinhole_model():
    T = np.eye(4)
    cam = camera_model_from_info(512, 424, [365.5, 0, 255.0, 0, 365.5, 205.0, 0, 0, 1], T, 0.5, 4.5)
    assert (cam.width, cam.height, cam.fx, cam.cy) == (512, 424, 365.5, 205.0)
    with pytest.raises(HardwareError, match="pinhole"):
        camera_model_from_info(512, 424, [0.0] * 9, T, 0.5, 4.5)


def test_hardware_config_needs_both_camera_fields_and_a_unit_quaternion():
    from pydantic import ValidationError

    with pytest.raises(ValidationError, match="both"):
        HardwareConfig(camera_translation_m=(1.0, 0.0, 1.0))
    with pytest.raises(ValidationError, match="unit norm"):
        HardwareConfig(camera_translation_m=(1.0, 0.0, 1.0), camera_quaternion_xyzw=(0.0, 0.0, 0.0, 2.0))
    hw = HardwareConfig(camera_translation_m=(1.0, 0.0, 1.0), camera_quaternion_xyzw=(0.0, 0.0, 0.0, 1.0))
    assert hw.has_camera_transform
    # The watchdog follows the connection: 5 periods of the rate the driver reaches.
    assert hw.connection_type == "usb" and hw.expected_state_rate_hz == pytest.approx(45.0)
    assert hw.state_timeout_s == pytest.approx(5 / 45.0)
    eth = HardwareConfig(connection_type="ethernet")
    assert eth.expected_state_rate_hz == pytest.approx(100.0) and eth.state_timeout_s == pytest.approx(0.05)
    slow = HardwareConfig(connection_type="ethernet", feedback_publish_rate_s=0.04)
    assert slow.expected_state_rate_hz == pytest.approx(25.0) and slow.state_timeout_s == pytest.approx(0.2)

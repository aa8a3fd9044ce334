"""The compiled frame passes equal, bit for bit, the vectorised numpy expressions they implement."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from compare.sensing import DepthNoise, DepthPipeline, DepthSensingSettings, load_workcell, make_data
from compare.sensing._frame_kernels import count_in_range, depth_from_buffer, remove_near_geoms, zero_at_or_beyond
from compare.sensing.camera import camera_model_from_mujoco, normalized_coordinates, valid_fraction
from compare.sensing.frames import DepthFrame
from compare.sensing.self_filter import SelfFilter
from tests.conftest import random_configuration

f32 = np.float32
_KINDS = (
    mujoco.mjtGeom.mjGEOM_SPHERE,
    mujoco.mjtGeom.mjGEOM_CAPSULE,
    mujoco.mjtGeom.mjGEOM_CYLINDER,
    mujoco.mjtGeom.mjGEOM_BOX,
)


# -- numpy references: one vectorised operation at a time -----------------------------------------
def depth_from_buffer_numpy(raw, f_minus_n, near, fn, normal, std, proportional, dropped, lo, hi):
    out = np.multiply(raw[::-1], f_minus_n)
    out += near
    np.divide(fn, out, out=out)
    if normal is not None:
        noise = normal * f32(std)
        if proportional:
            noise *= out
        out += noise
    if dropped is not None:
        out[dropped] = 0.0
    out[(out < lo) | (out > hi)] = 0.0
    return out


def signed_distance_numpy(kind, size, x, y, z):
    if kind == mujoco.mjtGeom.mjGEOM_SPHERE:
        return np.sqrt(x * x + y * y + z * z) - f32(size[0])
    if kind == mujoco.mjtGeom.mjGEOM_CAPSULE:
        zc = z - np.clip(z, f32(-size[1]), f32(size[1]))
        return np.sqrt(x * x + y * y + zc * zc) - f32(size[0])
    if kind == mujoco.mjtGeom.mjGEOM_CYLINDER:
        radial = np.sqrt(x * x + y * y) - f32(size[0])
        axial = np.abs(z) - f32(size[1])
        out_r, out_a = np.maximum(radial, 0), np.maximum(axial, 0)
        return np.sqrt(out_r * out_r + out_a * out_a) + np.minimum(np.maximum(radial, axial), 0)
    qx, qy, qz = np.abs(x) - f32(size[0]), np.abs(y) - f32(size[1]), np.abs(z) - f32(size[2])
    ox, oy, oz = np.maximum(qx, 0), np.maximum(qy, 0), np.maximum(qz, 0)
    inside = np.minimum(np.maximum(np.maximum(qx, qy), qz), 0)
    return np.sqrt(ox * ox + oy * oy + oz * oz) + inside


def remove_near_geoms_numpy(depth, boxes, centres, rots, kinds, sizes, radii, exact, xn, yn, m, k, std, prop):
    def margin(d):
        sigma = std * d if prop else std + 0.0 * d
        return m + k * sigma

    removed = 0
    with np.errstate(invalid="ignore", over="ignore"):
        for i, (v0, v1, u0, u1) in enumerate(boxes):
            if v0 < 0:
                continue
            c, r = centres[i].astype(np.float32), rots[i].astype(np.float32)
            crop = depth[v0:v1, u0:u1]
            d = crop
            x = xn[u0:u1][None, :] * d - c[0]
            y = yn[v0:v1][:, None] * d - c[1]
            z = d - c[2]
            lx = x * r[0, 0] + y * r[1, 0] + z * r[2, 0]
            ly = x * r[0, 1] + y * r[1, 1] + z * r[2, 1]
            lz = x * r[0, 2] + y * r[1, 2] + z * r[2, 2]
            if exact[i]:
                sd = signed_distance_numpy(int(kinds[i]), sizes[i], lx, ly, lz)
            else:
                sd = np.sqrt(lx * lx + ly * ly + lz * lz) - f32(radii[i])
            hit = (sd <= margin(d)) & (d > 0)
            removed += int(np.count_nonzero(hit))
            crop[hit] = 0.0
    return removed


# -- the kernels against them ---------------------------------------------------------------------
@pytest.mark.parametrize("noise", ["none", "constant", "proportional", "dropout-only"])
def test_buffer_to_metres_equals_numpy(noise):
    rng = np.random.default_rng(5)
    h, w = 424, 512
    raw = rng.random((h, w), dtype=np.float32)
    raw[:3] = 1.0  # far plane: out of range
    near, far = f32(0.05), f32(20.0)
    normal = rng.standard_normal((h, w), dtype=np.float32) if noise in ("constant", "proportional") else None
    dropped = rng.random((h, w), dtype=np.float32) < 0.07 if noise != "none" else None
    args = (raw, far - near, near, far * near)
    ref = depth_from_buffer_numpy(*args, normal, 0.01, noise == "proportional", dropped, f32(0.5), f32(4.5))
    out = np.empty_like(raw)
    depth_from_buffer(
        *args,
        np.empty((0, 0), np.float32) if normal is None else normal,
        f32(0.01),
        noise == "proportional",
        np.empty((0, 0), bool) if dropped is None else dropped,
        f32(0.5),
        f32(4.5),
        out,
    )
    np.testing.assert_array_equal(out, ref)
    assert 0 < np.count_nonzero(out) < out.size


def test_background_removal_equals_numpy_and_keeps_nan():
    rng = np.random.default_rng(6)
    depth = rng.uniform(0.0, 5.0, (424, 512)).astype(np.float32)
    depth[rng.random(depth.shape) < 0.05] = np.nan
    threshold = rng.uniform(0.0, 5.0, depth.shape).astype(np.float32)
    threshold[rng.random(depth.shape) < 0.2] = np.inf
    ref = depth.copy()
    ref[ref >= threshold] = 0.0
    out = np.empty_like(depth)
    zero_at_or_beyond(depth, threshold, out)
    np.testing.assert_array_equal(out, ref)
    zero_at_or_beyond(depth, threshold, depth)  # in place
    np.testing.assert_array_equal(depth, ref)
    assert np.isnan(depth).any() and (depth == 0).any()


def test_valid_count_equals_numpy_at_the_range_ends():
    rng = np.random.default_rng(8)
    cam = camera_model_from_mujoco(load_workcell())
    depth = rng.uniform(0.0, 5.0, (cam.height, cam.width)).astype(np.float32)
    depth[rng.random(depth.shape) < 0.05] = np.nan
    depth[:2] = f32(cam.min_range_m)  # exactly at the ends (float32): valid
    depth[2:4] = f32(cam.max_range_m)
    depth[4, :] = np.nextafter(f32(cam.max_range_m), f32(10.0))
    frame = DepthFrame(depth, 0.0, cam)
    ref = np.count_nonzero((depth >= cam.min_range_m) & (depth <= cam.max_range_m))
    assert count_in_range(depth, f32(cam.min_range_m), f32(cam.max_range_m)) == ref
    assert valid_fraction(frame) == ref / depth.size
    assert valid_fraction(DepthFrame(depth.astype(np.float64), 0.0, cam)) == pytest.approx(ref / depth.size, abs=1e-5)


@pytest.mark.parametrize("proportional", [False, True])
def test_geom_removal_equals_numpy_for_every_shape(proportional):
    """Random geoms of each kind (and one tested as its sphere) cut out of a random depth image."""
    rng = np.random.default_rng(7 + proportional)
    cam = camera_model_from_mujoco(load_workcell())
    xn, yn = (a.astype(np.float32) for a in normalized_coordinates(cam))
    depth = rng.uniform(0.6, 3.0, (cam.height, cam.width)).astype(np.float32)
    depth[rng.random(depth.shape) < 0.05] = 0.0
    depth[rng.random(depth.shape) < 0.01] = np.nan
    n = 24
    kinds = np.array([_KINDS[i % 4] if i % 5 else mujoco.mjtGeom.mjGEOM_ELLIPSOID for i in range(n)], dtype=np.int32)
    exact = np.isin(kinds, _KINDS)
    sizes = rng.uniform(0.05, 0.4, (n, 3))
    radii = np.linalg.norm(sizes, axis=1)
    centres = np.column_stack([rng.uniform(-0.8, 0.8, n), rng.uniform(-0.6, 0.6, n), rng.uniform(0.8, 2.8, n)])
    rots = np.array([np.linalg.qr(rng.standard_normal((3, 3)))[0] for _ in range(n)])
    boxes = np.column_stack(
        [rng.integers(0, 200, n), rng.integers(220, 424, n), rng.integers(0, 250, n), rng.integers(260, 512, n)]
    ).astype(np.int64)
    boxes[3] = -1  # out of view
    ref = depth.copy()
    settings = (f32(0.03), f32(5.0), f32(0.004), proportional)
    want = remove_near_geoms_numpy(ref, boxes, centres, rots, kinds, sizes, radii, exact, xn, yn, *settings)
    got = remove_near_geoms(
        depth, boxes, centres.astype(f32), rots.astype(f32), kinds, sizes.astype(f32), radii.astype(f32), exact, xn,
        yn, *settings,
    )  # fmt: skip
    np.testing.assert_array_equal(depth, ref)
    assert got == want > 10_000


@pytest.mark.rendering
def test_the_pipeline_filters_rendered_arm_frames_as_numpy_does(jaco):
    """Rendered noisy frames of the arm in random poses: the self-filter removes the same pixels."""
    model = load_workcell()
    settings = DepthSensingSettings(rho_m=0.5, noise_std_m=0.004, noise_proportional=True, dropout=0.02, seed=2)
    pipe = DepthPipeline(model, settings)
    data = make_data(model)
    rng = np.random.default_rng(9)
    sf: SelfFilter = pipe.self_filter
    try:
        removed_total = 0
        for _ in range(6):
            q = random_configuration(jaco, rng)
            data.qpos[: jaco.nq] = q
            mujoco.mj_forward(model, data)
            raw = pipe.render(data).depth_m
            depth = pipe.background.without(raw)
            ref = raw.copy()
            ref[ref >= pipe.background.threshold_m] = 0.0
            np.testing.assert_array_equal(depth, ref)
            got = sf.apply_inplace(depth, q=q)
            pos, rot = sf.geom_poses_from_q(q)
            T = sf.camera.transform_base_to_camera
            centres = (pos - T[:3, 3]) @ T[:3, :3]
            rots = np.einsum("ji,njk->nik", T[:3, :3], rot)
            boxes = sf.pixel_boxes(centres, ref.shape[1], ref.shape[0])
            want = remove_near_geoms_numpy(
                ref, boxes, centres, rots, sf._types, sf._sizes, sf._rbound, sf._exact, sf._xn, sf._yn,
                f32(sf.margin_m), f32(sf.noise_allowance), f32(sf.noise.std_m), sf.noise.proportional,
            )  # fmt: skip
            np.testing.assert_array_equal(depth, ref)
            assert got == want
            removed_total += got
        assert removed_total > 1000
    finally:
        pipe.close()


def test_depth_noise_std_is_the_kernel_sigma():
    """The kernel's σ(d) is DepthNoise.std_at in float32, both noise models."""
    d = np.array([0.7, 1.3, 2.9], dtype=np.float32)
    for noise in (DepthNoise(0.004), DepthNoise(0.004, proportional=True)):
        sigma = f32(noise.std_m) * d if noise.proportional else f32(noise.std_m) + f32(0.0) * d
        np.testing.assert_array_equal(np.asarray(noise.std_at(d), np.float32), sigma)

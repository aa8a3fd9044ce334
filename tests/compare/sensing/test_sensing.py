"""Obstacle distance: depth space (Flacco, paper sec. III) against the MuJoCo geometry, self-filter, robustness."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from compare.sensing import (
    PERSON_GROUP,
    STATIC_GROUP,
    DepthCamera,
    DepthDistance,
    DepthPipeline,
    DepthSensingSettings,
    GeometricDistance,
    GeometricObstacleSource,
    ObstacleReading,
    Person,
    PersonKeyframe,
    SensingError,
    StaticBackground,
    closest_on_capsules,
    control_point_positions,
    deproject,
    load_workcell,
    make_data,
    set_arm_configuration,
    truth_function,
)
from compare.sensing.camera import base_to_sensor
from compare.sensing.frames import DepthFrame
from tests.conftest import random_configuration

RHO = 0.5
CONTROL_POINTS = ("link_4", "link_6", "link_7")  # the Jaco²'s (robots.load("jaco2").control_points)


@pytest.fixture(scope="module")
def model():
    return load_workcell()


@pytest.fixture(scope="module")
def camera(model):
    from compare.sensing import camera_model_from_mujoco

    return camera_model_from_mujoco(model)


def random_person(model, rng) -> Person:
    """A person behind the arm (+y side), roughly facing the camera, hands anywhere in front."""
    pos = (rng.uniform(-0.4, 0.4), rng.uniform(0.85, 1.3))
    yaw = -math.pi / 2 + rng.uniform(-0.6, 0.6)
    hands = [tuple(rng.uniform([-0.5, 0.3, 0.1], [0.5, 0.8, 0.9])) if rng.random() < 0.8 else None for _ in range(2)]
    return Person(model, [PersonKeyframe(0.0, pos, yaw, right_hand=hands[0], left_hand=hands[1])])


def cone_is_free(apex: np.ndarray, tip: np.ndarray, radius: float, capsules: tuple) -> bool:
    """No capsule enters the cone from ``apex`` (the camera) to the disc of ``radius`` at ``tip``.

    For a control point P = ``tip`` whose true distance is ``radius``, this is "no occlusion":
    no surface in front of P casts a shadow (occluded half-line) closer to P than the truth.
    """
    t = np.linspace(0.0, 1.0, 400, endpoint=False)
    dist, _ = closest_on_capsules(apex + t[:, None] * (tip - apex), *capsules)
    return bool(np.all(dist > t * radius))


# -- geometric mode ------------------------------------------------------------------------------
def test_capsule_distance_matches_dense_sampling():
    rng = np.random.default_rng(1)
    a = rng.uniform(-1, 1, (6, 3))
    b = a + rng.uniform(-0.4, 0.4, (6, 3))
    b[0] = a[0]  # a sphere
    r = rng.uniform(0.03, 0.2, 6)
    points = rng.uniform(-1.5, 1.5, (50, 3))
    dist, closest = closest_on_capsules(points, a, b, r)
    t = np.linspace(0, 1, 2001)
    axis = a[:, None, :] + t[None, :, None] * (b - a)[:, None, :]  # (G, T, 3)
    brute = np.min(np.linalg.norm(points[:, None, None, :] - axis[None], axis=-1) - r[None, :, None], axis=(1, 2))
    np.testing.assert_allclose(dist, np.maximum(brute, 0.0), atol=1e-6)
    outside = dist > 0
    np.testing.assert_allclose(np.linalg.norm(points - closest, axis=1)[outside], dist[outside], atol=1e-12)
    # the closest point is on the union's surface
    surf, _ = closest_on_capsules(closest[outside], a, b, r)
    np.testing.assert_allclose(surf, 0.0, atol=1e-9)


def test_point_inside_a_capsule_reports_contact_at_itself():
    p = np.array([[0.0, 0.0, 0.05]])
    dist, closest = closest_on_capsules(p, np.zeros((1, 3)), np.array([[0.0, 0.0, 0.2]]), np.array([0.1]))
    assert dist[0] == 0.0
    np.testing.assert_array_equal(closest[0], p[0])


def test_geometric_mode_reports_range_and_truth_ignores_it(jaco, model):
    data = make_data(model)
    Person(model, [PersonKeyframe(0.0, (0.0, 0.9), -math.pi / 2, right_hand=(0.0, 0.35, 0.7))]).apply(0.0, data)
    mujoco.mj_forward(model, data)
    kin = jaco.kinematics(data.qpos[: jaco.nq])
    result = GeometricObstacleSource(GeometricDistance(model, rho_m=RHO), data, CONTROL_POINTS).update(1.5, kin)
    truth = truth_function(model, data, CONTROL_POINTS)(kin)
    assert set(result.readings) == set(CONTROL_POINTS) and not result.blind and result.stamp_s == 1.5
    for name, reading in result.readings.items():
        assert reading.in_range == (truth[name] <= RHO)
        if reading.in_range:
            assert reading.distance_m == pytest.approx(truth[name])
            p = kin.frame_position(name)
            assert np.linalg.norm(reading.closest_point - p) == pytest.approx(truth[name])
        else:
            assert reading == ObstacleReading.nothing()
    assert any(r.in_range for r in result.readings.values())


# -- depth space against geometry ----------------------------------------------------------------
@pytest.fixture(scope="module")
def person_rig(model):
    """Camera that sees the static scene and the person only (no arm: nothing else occludes)."""
    cam = DepthCamera(model, geom_groups=(STATIC_GROUP, PERSON_GROUP))
    background = StaticBackground.capture(cam, model)
    yield cam, background, DepthDistance(cam.camera, rho_m=RHO)
    cam.close()


def _filtered(cam, background, data) -> DepthFrame:
    frame = cam.render(data)
    depth = frame.depth_m.copy()
    background.apply_inplace(depth)
    return DepthFrame(depth, frame.stamp_s, frame.camera)


@pytest.mark.rendering
def test_depth_distance_is_within_2_cm_of_the_geometry_without_occlusion(model, person_rig):
    cam, background, distance = person_rig
    geometric = GeometricDistance(model, rho_m=math.inf)
    cam_pos = cam.camera.transform_base_to_camera[:3, 3]
    rng = np.random.default_rng(3)
    data = make_data(model)
    errors = []
    for _ in range(20):
        person = random_person(model, rng)
        person.apply(0.0, data)
        mujoco.mj_kinematics(model, data)
        frame = _filtered(cam, background, data)
        capsules = geometric.segments(data)
        # Control points in front of visible person points, towards the camera.
        vs, us = np.nonzero(frame.depth_m > 0)
        picks = rng.choice(vs.size, 12, replace=False)
        surface = deproject(cam.camera, np.column_stack([us[picks], vs[picks]]), frame.depth_m[vs[picks], us[picks]])
        towards = cam_pos - surface
        towards /= np.linalg.norm(towards, axis=1, keepdims=True)
        points = surface + rng.uniform(0.05, 0.4, (12, 1)) * towards
        truth, closest = closest_on_capsules(points, *capsules)
        result = distance.compute(frame, {str(i): p for i, p in enumerate(points)})
        for i, p in enumerate(points):
            # "fully visible, no occlusion": the camera sees P and its true closest point, and
            # nothing in front of P shadows the space around it
            visible = cone_is_free(cam_pos, closest[i], 0.005, capsules)
            if truth[i] > RHO - 0.03 or not (visible and cone_is_free(cam_pos, p, truth[i], capsules)):
                continue
            reading = result.readings[str(i)]
            assert reading.in_range
            errors.append(reading.distance_m - truth[i])
    errors = np.array(errors)
    assert errors.size >= 100
    assert np.max(np.abs(errors)) < 0.02, f"worst {np.max(np.abs(errors)):.4f} m"


@pytest.mark.rendering
def test_occluded_space_makes_the_estimate_conservative(model, person_rig):
    cam, background, distance = person_rig
    geometric = GeometricDistance(model, rho_m=math.inf)
    rng = np.random.default_rng(5)
    data = make_data(model)
    over, under = [], 0
    for _ in range(20):
        person = random_person(model, rng)
        person.apply(0.0, data)
        mujoco.mj_kinematics(model, data)
        frame = _filtered(cam, background, data)
        capsules = geometric.segments(data)
        torso = data.geom_xpos[model.geom("person_torso").id]
        points = torso + rng.uniform([-0.6, -0.7, -0.4], [0.6, 0.5, 0.5], (40, 3))  # all around, also behind
        truth, _ = closest_on_capsules(points, *capsules)
        result = distance.compute(frame, {str(i): p for i, p in enumerate(points)})
        for i in range(len(points)):
            if truth[i] > RHO - 0.02:
                continue
            estimate = result.readings[str(i)].distance_m
            assert math.isfinite(estimate), "an obstacle within rho must be seen (or its shadow)"
            over.append(estimate - truth[i])
            under += estimate < truth[i] - 0.05
    assert max(over) <= 0.01, f"estimate exceeds the truth by {max(over):.4f} m"
    assert under > 20  # occlusion did happen: hidden space counted as obstacle


@pytest.mark.rendering
def test_point_right_behind_the_torso_is_in_its_shadow(model, person_rig):
    cam, background, distance = person_rig
    data = make_data(model)
    Person(model, [PersonKeyframe(0.0, (0.0, 1.1), -math.pi / 2)]).apply(0.0, data)
    mujoco.mj_kinematics(model, data)
    frame = _filtered(cam, background, data)
    torso = data.geom_xpos[model.geom("person_torso").id]
    cam_pos = cam.camera.transform_base_to_camera[:3, 3]
    ray = (torso - cam_pos) / np.linalg.norm(torso - cam_pos)
    behind = torso + 0.45 * ray  # 0.29 m from the torso surface, hidden by it
    reading = distance.compute(frame, {"p": behind}).readings["p"]
    assert reading.in_range and reading.distance_m < 0.01
    # What is seen of it: the torso's front, no nearer than the truth (its back) and at most the
    # 0.45 m to the torso's axis on the ray, nearer the camera.
    assert reading.occluded and reading.surface_point is not None
    surface_gap = float(np.linalg.norm(reading.surface_point - behind))
    truth, _ = closest_on_capsules(behind[None, :], *GeometricDistance(model, rho_m=math.inf).segments(data))
    assert truth[0] - 0.01 <= surface_gap <= 0.45 + 0.01
    depth = base_to_sensor(cam.camera, np.array([reading.surface_point, behind]))[:, 2]
    assert depth[0] < depth[1]


def test_flacco_rule_on_a_single_pixel(camera):
    # One obstacle pixel; P in the sensor frame. Behind P (d_o >= d_p): the paper's distance
    # vector; in front of P: the occluded half-line, never farther than Flacco's point at d_p.
    distance = DepthDistance(camera, rho_m=2.0)
    u, v = 300, 180
    a, b = (u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy
    p_sensor = np.array([0.1, -0.05, 2.0])
    p_base = camera.transform_base_to_camera[:3, :3] @ p_sensor + camera.transform_base_to_camera[:3, 3]
    for d_o in (2.4, 1.6):
        depth = np.zeros((camera.height, camera.width), np.float32)
        depth[v, u] = d_o
        got = distance.compute(DepthFrame(depth, 0.0, camera), {"p": p_base}, 1.0).readings["p"]
        # paper sec. III: v_s = ((o_x - c_x) d_o - (p_x - c_x) d_p) / f s_x, ..., d_o - d_p
        d_eval = np.float32(d_o) if d_o >= p_sensor[2] else p_sensor[2]
        flacco = np.linalg.norm([a * d_eval - p_sensor[0], b * d_eval - p_sensor[1], d_eval - p_sensor[2]])
        if d_o >= p_sensor[2]:
            assert got.distance_m == pytest.approx(flacco, abs=1e-6)
        else:
            assert got.distance_m <= flacco + 1e-9
            ray = np.array([a, b, 1.0])
            foot = ray * (ray @ p_sensor) / (ray @ ray)
            assert got.distance_m == pytest.approx(np.linalg.norm(foot - p_sensor), abs=1e-6)
        o_sensor = base_to_sensor(camera, got.closest_point)
        np.testing.assert_allclose(np.cross(o_sensor, [a, b, 1.0]), 0.0, atol=1e-9)  # on the pixel's ray


# -- full pipeline: self-filter, table ------------------------------------------------------------
@pytest.fixture(scope="module")
def pipeline(model):
    pipe = DepthPipeline(model, DepthSensingSettings(rho_m=RHO))
    yield pipe
    pipe.close()


def _near_table_configurations(jaco, rng, count):
    out = []
    while len(out) < count:
        q = random_configuration(jaco, rng)
        kin = jaco.kinematics(q)
        heights = [kin.frame_position(f)[2] for f in (*CONTROL_POINTS, jaco.ee_frame)]
        if 0.02 < min(heights) < 0.15:
            out.append(q)
    return out


@pytest.mark.rendering
def test_arm_alone_is_never_an_obstacle_even_near_the_table(jaco, model, pipeline):
    rng = np.random.default_rng(11)
    data = make_data(model)
    Person(model).apply(0.0, data)  # nobody
    poses = [random_configuration(jaco, rng) for _ in range(20)] + _near_table_configurations(jaco, rng, 6)
    for q in poses:
        set_arm_configuration(model, data, q)
        mujoco.mj_forward(model, data)
        result = pipeline.sense(data, control_point_positions(jaco.kinematics(q), jaco.control_points))
        assert not result.blind
        assert all(not r.in_range for r in result.readings.values()), (q, result.distances())
        # nothing at all survives the filters: no arm pixel, no table or floor pixel
        assert np.count_nonzero(pipeline.filter(pipeline.render(data), q=q).depth_m > 0) == 0


@pytest.mark.rendering
def test_arm_alone_with_noise_and_dropout_is_still_not_an_obstacle(jaco, model):
    settings = DepthSensingSettings(rho_m=RHO, noise_std_m=0.005, noise_proportional=True, dropout=0.05, seed=3)
    pipe = DepthPipeline(model, settings)
    try:
        rng = np.random.default_rng(12)
        data = make_data(model)
        for q in [random_configuration(jaco, rng) for _ in range(8)] + _near_table_configurations(jaco, rng, 4):
            set_arm_configuration(model, data, q)
            mujoco.mj_forward(model, data)
            result = pipe.sense(data, control_point_positions(jaco.kinematics(q), jaco.control_points))
            assert all(not r.in_range for r in result.readings.values()), result.distances()
    finally:
        pipe.close()


@pytest.mark.rendering
def test_person_touching_the_arm_survives_the_self_filter(jaco, model, pipeline):
    data = make_data(model)
    kin = jaco.kinematics(data.qpos[: jaco.nq])
    points = control_point_positions(kin, CONTROL_POINTS)
    hand = points["link_4"] + np.array([0.0, 0.1, 0.06])  # the hand 2.3 cm off the elbow link
    Person(model, [PersonKeyframe(0.0, (0.0, 0.72), -math.pi / 2, right_hand=tuple(hand))]).apply(0.0, data)
    mujoco.mj_forward(model, data)
    gap = min(
        mujoco.mj_geomDistance(model, data, model.geom("person_r_hand").id, int(g), 1.0, None)
        for g in pipeline.self_filter.geom_ids
    )
    assert 0.0 < gap < pipeline.self_filter.margin_m
    truth = GeometricDistance(model, rho_m=math.inf).distances(data, points)
    reading = pipeline.sense(data, points).readings["link_4"]
    # Only the hand's pixels within the filter margin of the arm go; the rest of the hand is seen,
    # so the distance is off by at most the margin (the arm's blind zone), not by the hand's size.
    assert reading.in_range
    assert truth["link_4"] <= reading.distance_m + 0.002
    assert reading.distance_m <= truth["link_4"] + pipeline.self_filter.margin_m
    assert reading.distance_m < 0.08
    assert np.count_nonzero(pipeline.filter(pipeline.render(data), data=data).depth_m > 0) > 2000


@pytest.mark.rendering
def test_pipeline_matches_geometry_when_the_person_reaches_past_the_hand(jaco, model, pipeline):
    data = make_data(model)
    kin = jaco.kinematics(data.qpos[: jaco.nq])
    points = control_point_positions(kin, CONTROL_POINTS)
    reach = tuple(points["link_7"] + np.array([0.05, 0.25, 0.0]))
    Person(model, [PersonKeyframe(0.0, (0.05, 0.7), -math.pi / 2, right_hand=reach)]).apply(0.0, data)
    mujoco.mj_forward(model, data)
    truth = GeometricDistance(model, rho_m=math.inf).distances(data, points)
    result = pipeline.sense(data, points)
    for name in CONTROL_POINTS:
        assert truth[name] < RHO
        assert result.readings[name].distance_m == pytest.approx(truth[name], abs=0.01)
        # closest points are expressed in the base frame
        assert np.linalg.norm(result.readings[name].closest_point - points[name]) == pytest.approx(
            result.readings[name].distance_m
        )


@pytest.mark.rendering
def test_obstacle_source_filters_a_frame_once_and_tracks_the_control_points(jaco, model, pipeline):
    data = make_data(model)
    Person(model, [PersonKeyframe(0.0, (0.0, 0.9), -math.pi / 2, right_hand=(0.0, 0.4, 0.7))]).apply(0.0, data)
    mujoco.mj_forward(model, data)
    frame = pipeline.render(data)
    frames = [None, frame, frame]
    source = pipeline.source(lambda: frames.pop(0), CONTROL_POINTS)
    kin = jaco.kinematics(data.qpos[: jaco.nq])
    assert source.update(0.0, kin).blind  # no frame yet
    first = source.update(0.0, kin)
    cached = source._last
    again = source.update(0.01, kin)
    assert source._last is cached
    assert first.distances() == again.distances()
    assert not first.blind and any(r.in_range for r in first.readings.values())


# -- robustness: invalid pixels, blindness --------------------------------------------------------
def _points(camera):
    return {"a": camera.transform_base_to_camera[:3, 3] + camera.transform_base_to_camera[:3, 2] * 2.0}


@pytest.mark.parametrize("backend", DepthDistance.BACKENDS)
@pytest.mark.parametrize("fill", [0.0, np.nan, np.inf, -1.0])
def test_frames_without_valid_pixels_are_blind_and_never_obstacles(camera, backend, fill):
    frame = DepthFrame(np.full((camera.height, camera.width), fill, np.float32), 0.0, camera)
    result = DepthDistance(camera, blind_fraction=0.3, backend=backend).compute(frame, _points(camera))
    assert result.blind and result.valid_fraction == 0.0
    assert result.readings["a"] == ObstacleReading.nothing()


@pytest.mark.parametrize("backend", DepthDistance.BACKENDS)
def test_sparse_nan_and_dropout_are_skipped(camera, backend):
    rng = np.random.default_rng(2)
    depth = np.full((camera.height, camera.width), 2.2, np.float32)
    depth[rng.random(depth.shape) < 0.3] = np.nan
    depth[rng.random(depth.shape) < 0.3] = 0.0
    result = DepthDistance(camera, backend=backend).compute(DepthFrame(depth, 0.0, camera), _points(camera))
    assert not result.blind
    assert 0.45 < result.valid_fraction < 0.5
    assert result.readings["a"].distance_m == pytest.approx(0.2, abs=1e-3)  # the wall 0.2 m behind P


def test_blind_threshold_is_configurable(camera):
    depth = np.zeros((camera.height, camera.width), np.float32)
    depth[:100] = 3.0  # 23.6 % valid
    frame = DepthFrame(depth, 0.0, camera)
    assert DepthDistance(camera, blind_fraction=0.3).compute(frame, {}).blind
    assert not DepthDistance(camera, blind_fraction=0.2).compute(frame, {}).blind
    with pytest.raises(SensingError):
        DepthDistance(camera, blind_fraction=1.5)
    with pytest.raises(SensingError):
        DepthDistance(camera, backend="cuda")


def test_control_point_out_of_view_is_reported(camera):
    depth = np.full((camera.height, camera.width), 2.0, np.float32)
    behind = camera.transform_base_to_camera[:3, 3] - camera.transform_base_to_camera[:3, 2] * 1.5
    result = DepthDistance(camera).compute(DepthFrame(depth, 0.0, camera), {"behind": behind, **_points(camera)})
    assert result.out_of_view == ("behind",)
    assert not result.readings["behind"].in_range
    assert list(result.readings) == ["behind", "a"]


@pytest.mark.parametrize("support", [1, 3])
def test_numba_and_numpy_backends_agree(camera, support):
    rng = np.random.default_rng(4)
    depth = rng.uniform(0.6, 4.0, (camera.height, camera.width)).astype(np.float32)
    depth[rng.random(depth.shape) < 0.7] = 0.0
    depth[rng.random(depth.shape) < 0.05] = np.nan
    frame = DepthFrame(depth, 0.0, camera)
    cam_pos, forward = camera.transform_base_to_camera[:3, 3], camera.transform_base_to_camera[:3, 2]
    points = {str(i): cam_pos + forward * rng.uniform(0.2, 4.0) + rng.uniform(-0.6, 0.6, 3) for i in range(12)}
    fast = DepthDistance(camera, rho_m=0.4, min_support=support, backend="numba").compute(frame, points)
    ref = DepthDistance(camera, rho_m=0.4, min_support=support, backend="numpy").compute(frame, points)
    assert fast.pixels_visited == ref.pixels_visited > 0
    assert fast.out_of_view == ref.out_of_view
    for name in points:
        a, b = fast.readings[name], ref.readings[name]
        assert a.in_range == b.in_range and a.occluded == b.occluded
        if a.in_range:
            assert a.distance_m == pytest.approx(b.distance_m, abs=1e-9)
    # The closest measured (supported) point too.
    pts = np.array(list(points.values()))
    ev_fast = DepthDistance(camera, rho_m=0.4, backend="numba").evaluate(frame, pts, measured=True)
    ev_ref = DepthDistance(camera, rho_m=0.4, backend="numpy").evaluate(frame, pts, measured=True)
    np.testing.assert_allclose(ev_fast.measured_m, ev_ref.measured_m, rtol=0, atol=1e-9)


def test_surveillance_box_holds_every_pixel_within_rho(camera):
    # Brute force over the whole image finds nothing closer than what the box search finds.
    rng = np.random.default_rng(6)
    depth = rng.uniform(0.6, 4.0, (camera.height, camera.width)).astype(np.float32)
    depth[rng.random(depth.shape) < 0.9] = 0.0
    frame = DepthFrame(depth, 0.0, camera)
    cam_pos, forward = camera.transform_base_to_camera[:3, 3], camera.transform_base_to_camera[:3, 2]
    boxed = DepthDistance(camera, rho_m=0.5)
    for _ in range(10):
        p = cam_pos + forward * rng.uniform(0.3, 4.0) + rng.uniform(-0.8, 0.8, 3)
        ps = base_to_sensor(camera, p)
        vs, us = np.nonzero(depth > 0)
        a, b, d = (us - camera.cx) / camera.fx, (vs - camera.cy) / camera.fy, depth[vs, us].astype(float)
        s = np.maximum((a * ps[0] + b * ps[1] + ps[2]) / (a * a + b * b + 1), d)
        brute = np.sqrt(np.min((a * s - ps[0]) ** 2 + (b * s - ps[1]) ** 2 + (s - ps[2]) ** 2))
        got = boxed.compute(frame, {"p": p}).readings["p"]
        if brute <= 0.5:
            assert got.distance_m == pytest.approx(brute, abs=1e-6)
        else:
            assert not got.in_range


def test_compiled_capsule_distance_matches_numpy_reference():
    from compare.sensing._kernels import closest_on_capsules_kernel

    rng = np.random.default_rng(11)
    a = rng.uniform(-1, 1, (10, 3))
    b = a + rng.uniform(-0.3, 0.3, (10, 3))
    b[3] = a[3]  # a sphere
    r = rng.uniform(0.03, 0.15, 10)
    points = rng.uniform(-1.2, 1.2, (200, 3))
    d_ref, c_ref = closest_on_capsules(points, a, b, r)
    d_nb, c_nb = closest_on_capsules_kernel(points, a, b, r)
    np.testing.assert_allclose(d_nb, d_ref, atol=1e-12)
    np.testing.assert_allclose(c_nb, c_ref, atol=1e-12)


def test_geom_distances_are_the_segments_and_the_capsule_kernel_bit_for_bit(model):
    """The one-call path of GeometricDistance (segments formed in the kernel) gives the two-step numbers exactly."""
    from compare.sensing._kernels import closest_on_capsules_kernel

    geometric = GeometricDistance(model, rho_m=math.inf)
    rng = np.random.default_rng(12)
    data = make_data(model)
    for _ in range(20):
        random_person(model, rng).apply(0.0, data)
        mujoco.mj_kinematics(model, data)
        points = rng.uniform([-0.8, -0.2, 0.0], [0.8, 1.4, 1.6], (7, 3))
        want_d, want_c = closest_on_capsules_kernel(points, *geometric.segments(data))
        names = [str(i) for i in range(len(points))]
        assert geometric.distances_at(data, names, points) == dict(zip(names, want_d.tolist(), strict=True))
        result = geometric.compute(data, dict(zip(names, points, strict=True)))
        for i, name in enumerate(names):
            assert result.readings[name].distance_m == want_d[i]
            np.testing.assert_array_equal(result.readings[name].closest_point, want_c[i])


@pytest.mark.parametrize("backend", DepthDistance.BACKENDS)
def test_a_lone_flying_pixel_is_not_a_measured_point(camera, backend):
    # A wall 2.5 m away and one pixel 40 cm nearer than all its neighbours (the rasteriser's or a
    # real sensor's flying pixel): the closest measured point is on the wall, the half-line still counts.
    depth = np.zeros((camera.height, camera.width), np.float32)
    depth[150:250, 200:300] = 2.5
    depth[200, 250] = 2.1
    frame = DepthFrame(depth, 0.0, camera)
    distance = DepthDistance(camera, rho_m=1.0, backend=backend)
    p = camera.transform_base_to_camera[:3, :3] @ np.array([0.0, 0.0, 1.9]) + camera.transform_base_to_camera[:3, 3]
    ev = distance.evaluate(frame, p[None, :], measured=True)
    assert ev.measured_m[0] == pytest.approx(0.6, abs=0.01)  # the wall, not the lone pixel
    assert ev.distance_m[0] < 0.25  # the lone pixel's hidden half-line passes near P
    depth[201, 250] = 2.12  # a neighbour within 5 cm: now a measured surface
    assert distance.evaluate(frame, p[None, :], measured=True).measured_m[0] == pytest.approx(0.2, abs=0.01)


@pytest.mark.parametrize("backend", DepthDistance.BACKENDS)
def test_min_support_from_the_config_ignores_one_stray_pixel_near_a_control_point(camera, backend):
    # The wall 2.5 m away, P 0.6 m in front of it and one stray pixel at 2.1 m, 0.2 m behind P (as
    # the stand-in's render once gave beside link_6): the minimum takes it, the second-nearest not.
    from compare.config import SensorConfig
    from compare.sensing.pipeline import DepthSensingSettings

    depth = np.zeros((camera.height, camera.width), np.float32)
    depth[150:250, 200:300] = 2.5
    frame = DepthFrame(depth, 0.0, camera)
    p = camera.transform_base_to_camera[:3, :3] @ np.array([0.0, 0.0, 1.9]) + camera.transform_base_to_camera[:3, 3]
    stray = depth.copy()
    stray[int(round(camera.cy)), int(round(camera.cx))] = 2.1
    readings = {}
    for support in (1, 2):
        s = DepthSensingSettings.from_sensor_config(SensorConfig(min_support=support, rho_m=1.0))
        assert s.min_support == support
        distance = DepthDistance(camera, s.rho_m, s.blind_fraction, s.min_support, backend=backend)
        clean = distance.compute(frame, {"p": p}).readings["p"].distance_m
        assert clean == pytest.approx(0.6, abs=0.01)
        readings[support] = distance.compute(DepthFrame(stray, 0.0, camera), {"p": p}).readings["p"].distance_m
    assert readings[1] == pytest.approx(0.2, abs=0.01)  # the paper's minimum: the stray pixel
    assert readings[2] == pytest.approx(0.6, abs=0.01)  # the second-nearest: the wall

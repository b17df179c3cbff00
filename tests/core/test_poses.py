import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from spm_data.core.poses import (camera_pose, camera_poses, cv_to_gl_camera_to_world, gl_camera_to_world_to_cv,
                            intrinsics_from_fov, label_to_pose, pose_to_label, project_points, wrap_degrees)

angles = st.floats(-720, 720, allow_nan=False)
elev = st.floats(-89.9, 89.9, allow_nan=False)
dist = st.floats(0.05, 50, allow_nan=False)
offset = st.tuples(*[st.floats(-1, 1, allow_nan=False)] * 3)


@settings(max_examples=200, deadline=None)
@given(angles, elev, st.floats(-180, 180, allow_nan=False), dist, offset)
def test_pose_is_a_rotation_looking_at_the_target(az, el, roll, d, look_at):
    R, t = camera_pose(az, el, roll, d, look_at)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-9)
    assert abs(np.linalg.det(R) - 1) < 1e-9
    K = intrinsics_from_fov(40, 128, 96)
    # The target projects to the principal point, at depth d.
    uv, z = project_points(np.array([look_at]), K, R, t)
    np.testing.assert_allclose(uv[0], K[:2, 2], atol=1e-6)
    np.testing.assert_allclose(z[0], d, rtol=1e-9)
    # The camera centre sits at distance d from the target.
    centre = -R.T @ t
    np.testing.assert_allclose(np.linalg.norm(centre - np.asarray(look_at)), d, rtol=1e-9)


@settings(max_examples=200, deadline=None)
@given(angles, elev, st.floats(-170, 170, allow_nan=False), dist)
def test_object_origin_projects_where_t_says(az, el, roll, d):
    R, t = camera_pose(az, el, roll, d, (0.05, -0.02, 0.03))
    K = intrinsics_from_fov(35, 128, 128)
    uv, _ = project_points(np.zeros((1, 3)), K, R, t)
    expect = (K @ t)[:2] / (K @ t)[2]
    np.testing.assert_allclose(uv[0], expect, atol=1e-9)


@settings(max_examples=200, deadline=None)
@given(angles, elev, st.floats(-80, 80, allow_nan=False), dist)
def test_label_round_trip(az, el, roll, d):
    R, t = camera_pose(az, el, roll, d)
    y = pose_to_label(R, t)
    assert y.shape == (6,) and np.all(y[:3] > -180) and np.all(y[:3] <= 180)
    R2, t2 = label_to_pose(y)
    np.testing.assert_allclose(R2, R, atol=1e-9)
    np.testing.assert_allclose(t2, t, atol=1e-12)


@settings(max_examples=100, deadline=None)
@given(angles, elev, st.floats(-180, 180, allow_nan=False), dist, offset)
def test_gl_blender_round_trip(az, el, roll, d, look_at):
    R, t = camera_pose(az, el, roll, d, look_at)
    M = cv_to_gl_camera_to_world(R, t)
    # The GL camera looks down its -z: towards the target.
    forward = -M[:3, 2]
    to_target = np.asarray(look_at) - M[:3, 3]
    np.testing.assert_allclose(forward, to_target / np.linalg.norm(to_target), atol=1e-9)
    R2, t2 = gl_camera_to_world_to_cv(M)
    np.testing.assert_allclose(R2, R, atol=1e-12)
    np.testing.assert_allclose(t2, t, atol=1e-12)


def test_default_path_labels_read_as_documented():
    az = np.arange(0, 360, 5.0)
    for el in (0.0, 30.0, 60.0):
        R, t = camera_poses(az, el, 0.0, 0.7)
        y = pose_to_label(R, t)
        np.testing.assert_allclose(y[:, 0], wrap_degrees(90 + el), atol=1e-9)
        np.testing.assert_allclose(y[:, 1], 0.0, atol=1e-9)
        np.testing.assert_allclose(y[:, 2], wrap_degrees(-(az + 90)), atol=1e-9)
        np.testing.assert_allclose(y[:, 3:], [[0, 0, 0.7]] * len(az), atol=1e-12)


def test_up_is_up_and_roll_turns_the_image():
    K = intrinsics_from_fov(35, 128, 128)
    top = np.array([[0, 0, 0.1]])
    R, t = camera_pose(40, 20, 0, 0.7)
    uv, _ = project_points(top, K, R, t)
    assert uv[0, 1] < K[1, 2] - 5 and abs(uv[0, 0] - K[0, 2]) < 1e-6  # straight above the centre
    R, t = camera_pose(40, 20, 90, 0.7)
    uv, _ = project_points(top, K, R, t)
    # Camera x turned onto its old y (down), so the object's up (old -y) now points along -u.
    assert uv[0, 0] < K[0, 2] - 5 and abs(uv[0, 1] - K[1, 2]) < 1e-6


def test_camera_at_azimuth_zero_sits_on_plus_x():
    R, t = camera_pose(0, 0, 0, 2.0)
    np.testing.assert_allclose(-R.T @ t, [2, 0, 0], atol=1e-12)
    R, t = camera_pose(90, 0, 0, 2.0)
    np.testing.assert_allclose(-R.T @ t, [0, 2, 0], atol=1e-12)
    R, t = camera_pose(0, 90, 0, 2.0)
    np.testing.assert_allclose(-R.T @ t, [0, 0, 2], atol=1e-12)


def test_intrinsics_are_centred_on_pixel_centres():
    K = intrinsics_from_fov(90, 100, 50)
    np.testing.assert_allclose(K[:2, 2], [49.5, 24.5])
    np.testing.assert_allclose(K[1, 1], 25.0)
    assert K[0, 0] == K[1, 1]


def test_label_to_view_inverts_camera_poses_roll_included():
    from spm_data.core.poses import label_to_view

    rng = np.random.default_rng(4)
    az, el, roll = rng.uniform(-179, 180, 50), rng.uniform(-85, 85, 50), rng.uniform(-179, 180, 50)
    dist = rng.uniform(0.3, 2.0, 50)
    R, t = camera_poses(az, el, roll, dist)
    view = label_to_view(pose_to_label(R, t))
    for key, want in (("azimuth", az), ("elevation", el), ("roll", roll), ("distance", dist)):
        assert np.allclose(view[key], want, atol=1e-9), key
    one = label_to_view(pose_to_label(*camera_pose(30, 20, 0, 0.7)))
    assert np.isclose(one["azimuth"], 30) and np.isclose(one["elevation"], 20) and np.isclose(one["distance"], 0.7)


def test_k_corner_origin_round_trip_is_exact():
    from spm_data.core.poses import K_from_corner_origin, K_to_corner_origin, intrinsics_from_fov

    K = intrinsics_from_fov(35.0, 128, 96)
    bop = K_to_corner_origin(K)
    assert (bop[0, 2], bop[1, 2]) == (64.0, 48.0)   # centred: W / 2, H / 2 from the corner
    assert (K_from_corner_origin(bop) == K).all() and (K[0, 2], K[1, 2]) == (63.5, 47.5)
    assert bop[0, 0] == K[0, 0] and K_to_corner_origin(K) is not K


def test_gltf_to_object_is_a_rotation_taking_up_and_front():
    from spm_data.core.poses import GLTF_TO_OBJECT, is_rotation

    assert is_rotation(GLTF_TO_OBJECT)
    np.testing.assert_array_equal(GLTF_TO_OBJECT @ [0, 1, 0], [0, 0, 1])   # glTF up -> +z
    np.testing.assert_array_equal(GLTF_TO_OBJECT @ [0, 0, 1], [1, 0, 0])   # glTF front -> +x


def test_a_capture_camera_to_world_becomes_our_pose_in_the_scaled_recentred_object_frame():
    import pytest

    from spm_data.core.poses import gl_camera_to_world_to_object
    from spm_data.errors import SpmError

    R, t = camera_pose(40, 25, 10, 0.7)
    scale, center = 0.5, np.array([1.0, -2.0, 3.0])
    M = cv_to_gl_camera_to_world(R, t)
    M[:3, 3] = M[:3, 3] / scale + center          # the same camera in world units, the object at center
    R2, t2 = gl_camera_to_world_to_object(M, scale, center)
    np.testing.assert_allclose(R2, R, atol=1e-12)
    np.testing.assert_allclose(t2, t, atol=1e-12)
    # A world point and its object-frame point project to the same pixel.
    X_obj = np.array([0.05, -0.02, 0.03])
    cam = R @ X_obj + t
    world = X_obj / scale + center
    gl = np.linalg.inv(M) @ np.r_[world, 1.0]
    np.testing.assert_allclose(np.diag([1.0, -1.0, -1.0]) @ gl[:3] * scale, cam, atol=1e-12)
    with pytest.raises(SpmError, match="not a rotation"):
        gl_camera_to_world_to_object(np.diag([2.0, 2.0, 2.0, 1.0]))
    with pytest.raises(SpmError, match="last row"):
        gl_camera_to_world_to_object(np.vstack([M[:3], [0, 0, 1, 1]]))


def test_one_rotation_tolerance_and_the_nearest_rotation_is_exact():
    from spm_data.core.poses import (ROTATION_TOLERANCE, STORED_ROTATION_TOLERANCE, is_rotation, nearest_rotation,
                                     rotation_error)

    R, _ = camera_pose(30.0, 20.0, 5.0, 1.0)
    off = R + np.array([[0.0, 4e-5, 0.0], [0.0, 0.0, 0.0], [1e-5, 0.0, 0.0]])   # a capture's 1e-5 rounding
    assert 1e-5 < rotation_error(off) < ROTATION_TOLERANCE and is_rotation(off)
    fixed = nearest_rotation(off)
    assert rotation_error(fixed) < 1e-14 < STORED_ROTATION_TOLERANCE
    assert np.abs(fixed - R).max() < 5e-5                    # the rotation it was meant to be
    np.testing.assert_allclose(nearest_rotation(R), R, atol=1e-15)
    assert not is_rotation(R + 2e-4) and not is_rotation(np.diag([1.0, 1.0, -1.0]))   # beyond it; a mirror
    assert rotation_error(np.full((3, 3), np.nan)) == np.inf
    assert np.linalg.det(nearest_rotation(np.diag([1.0, 1.0, -1.0]))) > 0

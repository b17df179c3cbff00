"""N3M online stages on synthetic correspondences with a known pose and known noise."""

import numpy as np
from scipy.spatial.transform import Rotation

from spm_model.methods.n3m_points import build_index
from spm_model.methods.n3m_pose import estimate, marker_hypotheses, match, ransac_pose, reprojection_errors

K = np.array([[400.0, 0.0, 127.5], [0.0, 400.0, 127.5], [0.0, 0.0, 1.0]])
R_TRUE = Rotation.from_euler("XYZ", [100.0, -20.0, 35.0], degrees=True).as_matrix()
T_TRUE = np.array([0.01, -0.02, 0.7])


def scene(n=60, noise=0.5, seed=0):
    """n object points in a 0.2 m cube, their projections with Gaussian pixel noise."""
    rng = np.random.default_rng(seed)
    xyz = rng.uniform(-0.1, 0.1, (n, 3))
    cam = xyz @ R_TRUE.T + T_TRUE
    uv = (cam @ K.T)[:, :2] / cam[:, 2:3] + rng.normal(0.0, noise, (n, 2))
    return xyz, uv


def angle_deg(Ra, Rb):
    return np.degrees(np.arccos(np.clip((np.trace(Ra.T @ Rb) - 1) / 2, -1, 1)))


def test_ransac_recovers_the_pose_within_the_noise_bound_despite_outliers():
    xyz, uv = scene(noise=0.5)
    rng = np.random.default_rng(1)
    uv[:18] = rng.uniform(0, 255, (18, 2))                          # 30% gross outliers
    R, t, inliers, source = estimate(np.zeros((0, 5), int), np.arange(60), xyz, uv, K, tol=3.0,
                                     min_inliers=8, fallback=True)
    # 0.5 px at f = 400 is 0.07 deg per point; 42 inliers spread over ~16 deg of view
    # average it down: 0.3 deg is a loose bound, 0.75 mm x z-sensitivity for translation.
    assert source == "ransac"
    assert angle_deg(R, R_TRUE) < 0.3
    assert np.linalg.norm(t - T_TRUE) < 0.005
    assert 38 <= inliers <= 42


def test_ransac_draws_the_same_samples_whatever_the_threads_generator_holds():
    import cv2

    xyz, uv = scene(n=40, noise=0.5)
    rng = np.random.default_rng(3)
    uv[:26] = rng.uniform(0, 255, (26, 2))                          # 65% outliers: samples matter
    found = set()
    for state in (0, 1, 12345):
        cv2.setRNGSeed(state)
        cv2.randu(np.zeros(16), 0.0, 1.0)
        R, t, inliers, source = estimate(np.zeros((0, 5), int), np.arange(40), xyz, uv, K, tol=3.0,
                                         min_inliers=8, fallback=True)
        found.add((R.tobytes(), t.tobytes(), inliers, source))
    assert len(found) == 1 and next(iter(found))[3] == "ransac"


def test_markers_give_the_pose_first_and_a_wrong_marker_is_rejected():
    xyz, uv = scene(noise=0.3)
    markers = np.array([[0, 1, 2, 3, 4], [5, 6, 7, 8, 9]])
    uv_bad = uv.copy()
    uv_bad[[5, 6]] = uv_bad[[6, 5]]                                  # two swapped matches
    poses = marker_hypotheses(markers, np.arange(60), xyz, uv_bad, K, tol=3.0)
    assert len(poses) == 1                                           # marker 2 fails its own check
    assert np.all(reprojection_errors(xyz[:5], uv[:5], K, *poses[0]) <= 3.0)
    R, t, inliers, source = estimate(markers, np.arange(60), xyz, uv_bad, K, tol=3.0, min_inliers=8,
                                     fallback=False)
    assert source == "n3m" and angle_deg(R, R_TRUE) < 0.3 and inliers == 58


def test_validation_rejects_random_and_degenerate_match_sets():
    xyz, _ = scene()
    rng = np.random.default_rng(2)
    noise_uv = rng.uniform(0, 255, (60, 2))                          # matches that mean nothing
    assert estimate(np.array([[0, 1, 2, 3, 4]]), np.arange(60), xyz, noise_uv, K, tol=3.0,
                    min_inliers=8, fallback=True) is None
    few_xyz, few_uv = scene(n=6)                                     # a right pose, too few points
    assert estimate(np.zeros((0, 5), int), np.arange(6), few_xyz, few_uv, K, tol=3.0, min_inliers=8,
                    fallback=True) is None
    assert marker_hypotheses(np.array([[0, 1, 2, 3, 4]]), np.arange(3), xyz, noise_uv, K, tol=3.0) == []


def test_ransac_pose_is_the_fallback_alone_and_estimate_without_it_stays_with_the_markers():
    xyz, uv = scene(noise=0.5)
    uv[:18] = np.random.default_rng(1).uniform(0, 255, (18, 2))      # 30% gross outliers
    markers = np.array([[0, 1, 2, 3, 4]])                            # every point an outlier: fails
    assert marker_hypotheses(markers, np.arange(60), xyz, uv, K, tol=3.0) == []
    assert estimate(markers, np.arange(60), xyz, uv, K, tol=3.0, min_inliers=8, fallback=False) is None
    R, t, inliers, source = ransac_pose(xyz, uv, K, tol=3.0, min_inliers=8)
    assert source == "ransac" and angle_deg(R, R_TRUE) < 0.3 and 38 <= inliers <= 42
    via = estimate(markers, np.arange(60), xyz, uv, K, tol=3.0, min_inliers=8, fallback=True)
    assert np.array_equal(via[0], R) and np.array_equal(via[1], t) and via[2:] == (inliers, "ransac")
    assert ransac_pose(xyz[:7], uv[:7], K, tol=3.0, min_inliers=8) is None   # fewer matches than inliers needed

def test_match_keeps_distinct_matches_and_drops_ambiguous_ones():
    rng = np.random.default_rng(3)
    desc = rng.uniform(0, 255, (4, 128)).astype(np.float32)
    stored = np.concatenate([desc, desc[:1] + 1.0, desc[1:2] + 2.0])  # points 0..3; copies of 0 and 1
    xyz = np.array([[0, 0, 0], [0.05, 0, 0], [0.1, 0, 0], [0.1, 0, 0.0001], [0, 0, 0], [0.06, 0, 0]])
    point = np.array([0, 1, 2, 3, 0, 1])                             # point 1's copy is 1 cm away
    queries = desc + np.array([[0.5], [1.0], [0.5], [0.5]], dtype=np.float32)  # query 1 halfway to the copy
    keypoint, matched = match(build_index(stored), xyz, point, queries, ratio=0.8, same_radius=0.002)
    # 0: its copy is at the same place (not a rival): kept. 1: the copy 1 cm off is a
    # rival as near as the original: dropped. 2 and 3 sit together: each kept.
    assert sorted(matched.tolist()) == [0, 2, 3]
    assert sorted(keypoint.tolist()) == [0, 2, 3]


def test_match_with_nothing_distinct_or_no_keypoint_gives_no_match():
    rng = np.random.default_rng(4)
    desc = rng.uniform(0, 255, (2, 128)).astype(np.float32)
    stored = np.concatenate([desc, desc + 2.0])                      # every point has a twin elsewhere
    xyz = np.array([[0, 0, 0], [0.05, 0, 0], [0.1, 0, 0], [0.15, 0, 0]])
    queries = desc + 1.0                                              # halfway: never distinct
    for q in (queries, np.zeros((0, 128), np.float32)):
        keypoint, matched = match(build_index(stored), xyz, np.arange(4), q, ratio=0.8, same_radius=0.002)
        assert len(keypoint) == 0 and len(matched) == 0


def test_marker_rows_are_where_each_marker_point_was_matched_last():
    from spm_model.methods.n3m_pose import _marker_rows

    rng = np.random.default_rng(0)
    for _ in range(200):
        markers = rng.integers(0, 60, (int(rng.integers(1, 30)), 5))
        matched = rng.integers(0, 60, int(rng.integers(1, 40)))      # repeats too
        lookup = {int(p): i for i, p in enumerate(matched)}            # the definition: last match wins
        rows, found = _marker_rows(markers, matched)
        for marker, r, f in zip(markers, rows, found):
            assert list(r[f]) == [lookup[int(p)] for p in marker if int(p) in lookup]
            assert np.all(r[~f] == -1)

"""N3M points: lifting, merging, visibility and distinctiveness on scenes with known answers."""

import cv2
import numpy as np

from spm_model.methods.n3m_points import (distinctiveness, lift, make_sift, merge_observations, sift_features,
                                          small_depth, visibility)

K = np.array([[100.0, 0.0, 31.5], [0.0, 100.0, 31.5], [0.0, 0.0, 1.0]])
R = np.eye(3)
T = np.array([0.0, 0.0, 0.5])          # the object origin 0.5 m ahead


def plane_depth(h=64, w=64):
    """Depth of the plane z_obj = 0 (camera z = 0.5) on the central 40 x 40 pixels."""
    depth = np.zeros((h, w), np.float32)
    depth[12:52, 12:52] = 0.5
    return depth


def test_lift_puts_pixels_on_the_plane_and_refuses_silhouettes():
    uv = np.array([[31.5, 31.5], [41.5, 21.5], [12.0, 30.0], [5.0, 5.0]])
    xyz, ok = lift(uv, plane_depth(), K, R, T)
    assert ok.tolist() == [True, True, False, False]                 # edge pixel, background
    np.testing.assert_allclose(xyz[0], [0.0, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(xyz[1], [0.05, -0.05, 0.0], atol=1e-12)  # 10 px at f = 100, 0.5 m


def test_merge_groups_observations_within_the_radius():
    rng = np.random.default_rng(0)
    centres = np.array([[0.0, 0.0, 0.0], [0.01, 0.0, 0.0], [0.0, 0.03, 0.0]])
    xyz = np.repeat(centres, 5, axis=0) + rng.normal(0, 0.0003, (15, 3))
    labels = merge_observations(xyz, np.zeros(15), radius=0.002)
    assert len(np.unique(labels)) == 3
    assert all(len(np.unique(labels[i * 5:(i + 1) * 5])) == 1 for i in range(3))


def test_visibility_needs_the_point_on_the_visible_surface():
    depth = small_depth(plane_depth())
    points = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, -0.1], [0.5, 0.0, 0.0]])  # on, behind-ish, outside
    vis = visibility(points, [depth], [(64, 64)], [K], R[None], T[None])
    assert vis[:, 0].tolist() == [True, False, False]


def test_distinctiveness_scores_confusable_descriptors_zero():
    rng = np.random.default_rng(1)
    a, b = rng.uniform(0, 255, (2, 128))
    desc = np.array([a, a + 1, b, b + 40, b + 41]).astype(np.float32)
    xyz = np.array([[0, 0, 0], [0, 0, 0], [0.1, 0, 0], [0.2, 0, 0], [0.2, 0, 0]], dtype=float)
    score = distinctiveness(desc, xyz, same_radius=0.002, ratio=0.8)
    # a: its twin at the same place is far nearer than anything else: distinct. b: alone
    # at its place, nearest rival elsewhere: not distinct. b+40 and b+41: twins, distinct.
    assert score.tolist() == [1.0, 1.0, 0.0, 1.0, 1.0]


def test_sift_upsampling_keeps_keypoints_in_the_original_pixels_and_mask():
    rng = np.random.default_rng(2)
    img = cv2.resize(rng.integers(0, 255, (16, 16), dtype=np.uint8), (64, 64), interpolation=cv2.INTER_NEAREST)
    rgb = np.dstack([img] * 3)
    mask = np.zeros((64, 64), bool)
    mask[8:56, 8:56] = True
    sift = make_sift(0)
    uv1, d1 = sift_features(rgb, mask, side=64, sift=sift)
    uv2, d2 = sift_features(rgb, mask, side=128, sift=sift)
    assert len(uv2) > len(uv1) > 0 and d2.shape == (len(uv2), 128)
    for uv in (uv1, uv2):
        assert np.all((uv >= 7.5) & (uv <= 56.5))                  # inside the mask, original pixels
    # Corners found at both scales sit at the same original pixels (within a pixel).
    near = np.linalg.norm(uv1[:, None] - uv2[None], axis=2).min(axis=1)
    assert np.median(near) < 1.0


def test_group_medians_and_spread_picks_are_numpys_group_by_group():
    from spm_model.methods.n3m_points import group_medians, spread_picks

    rng = np.random.default_rng(3)
    lengths = rng.integers(1, 9, 200)
    starts = np.r_[0, np.cumsum(lengths)]
    values = np.round(rng.normal(size=(starts[-1], 3)), 2)            # rounded: ties inside groups
    medians = group_medians(values, starts)
    expected = np.array([np.median(values[a:b], axis=0) for a, b in zip(starts[:-1], starts[1:])])
    assert medians.tobytes() == expected.tobytes()
    for length, pick in zip(lengths, spread_picks(lengths, 4)):
        assert np.array_equal(pick, np.unique(np.rint(np.linspace(0, length - 1, min(length, 4))).astype(int)))
    assert [p.tolist() for p in spread_picks(np.array([1, 2, 7]), 3)] == [[0], [0, 1], [0, 3, 6]]

"""spm_model.spm.keypoints: SIFT keypoints in the mask, RANSAC inliers against a known homography,
the training rule against the path neighbour, and a frame through to its manifold vector."""

import cv2
import numpy as np
import pytest

from spm_data.core.shapes import procedural_mesh
from spm_data.core.paths import camera_path
from spm_data.render import make_renderer
from spm_data.core.specs import parse_spec
from spm_model.spm.bunches import fit_bunches
from spm_model.spm.keypoints import frame_keypoints, homography_inliers, sift_keypoints, sift_locations
from spm_model.spm.manifold import initial_manifold


@pytest.fixture(scope="module")
def two_neighbours():
    spec = parse_spec('class = "box"\n[render]\nrenderer = "pyrender"')
    r = make_renderer(spec)
    r.set_mesh(procedural_mesh("box", 1))
    path = camera_path(spec.camera)
    R, t = path.poses(np.array([10, 11]))  # consecutive: one 5-degree step apart
    return [r.render(R[i], t[i]) for i in range(2)]


def test_sift_keypoints_lie_in_the_mask(two_neighbours):
    frame = two_neighbours[0]
    loc, desc = sift_keypoints(frame["rgb"], frame["mask"])
    assert len(loc) >= 30 and desc.shape == (len(loc), 128)
    cols, rows = np.round(loc[:, 0]).astype(int), np.round(loc[:, 1]).astype(int)
    near = cv2.dilate(frame["mask"], np.ones((3, 3), np.uint8))
    assert near[rows, cols].all()


def test_sift_locations_are_sift_keypoints_without_descriptors(two_neighbours):
    for frame in two_neighbours:
        for mask in (frame["mask"], None):
            loc, _ = sift_keypoints(frame["rgb"], mask)
            assert len(loc) >= 30
            np.testing.assert_array_equal(sift_locations(frame["rgb"], mask), loc)
    assert sift_locations(np.zeros((32, 32, 3), np.uint8)).shape == (0, 2)  # flat: none, still (N, 2)


def test_ransac_against_a_known_homography():
    rng = np.random.default_rng(0)
    img = np.zeros((160, 160, 3), np.uint8)
    for _ in range(120):
        cv2.circle(img, tuple(int(v) for v in rng.integers(10, 150, 2)), int(rng.integers(2, 7)),
                   tuple(int(v) for v in rng.integers(40, 255, 3)), -1)
    H = np.array([[1.02, 0.03, 4.0], [-0.02, 0.99, -3.0], [0, 0, 1]])
    warped = cv2.warpPerspective(img, H, (160, 160))
    la, da = sift_keypoints(img)
    lb, db = sift_keypoints(warped)
    keep = homography_inliers(la, da, lb, db)
    assert keep.sum() >= 30
    # Kept keypoints map through H onto keypoints of the warped image.
    mapped = cv2.perspectiveTransform(la[keep][None].astype(np.float32), H)[0]
    nearest = np.min(np.linalg.norm(mapped[:, None] - lb[None], axis=2), axis=1)
    assert np.median(nearest) < 1.0
    # No shared structure: nothing survives.
    assert homography_inliers(la, da, la[:3], da[:3]).sum() == 0


def test_training_rule_keeps_inliers_against_the_path_neighbour(two_neighbours):
    a, b = two_neighbours
    everything = frame_keypoints(a["rgb"], a["mask"])
    kept = frame_keypoints(a["rgb"], a["mask"], b["rgb"], b["mask"])
    assert 8 <= len(kept) <= len(everything)
    assert {tuple(p) for p in kept} <= {tuple(p) for p in everything}


def test_frame_to_manifold_end_to_end(two_neighbours):
    a, b = two_neighbours
    kept = frame_keypoints(a["rgb"], a["mask"], b["rgb"], b["mask"])
    if len(kept) < 16:  # the box is well textured: the test asserts it, not skips it
        pytest.fail(f"only {len(kept)} inlier keypoints on a textured box")
    vector, ecc = initial_manifold(fit_bunches(kept).means)
    assert vector.shape == (16,) and np.isfinite(vector).all() and 0 <= ecc < 1

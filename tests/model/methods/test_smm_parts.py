"""spm_model.methods.smm_parts: the object-centred frame, RootSIFT, features that do
not move with the object's image position, and parts learned from and detected in
features whose clusters are known."""

import cv2
import numpy as np
import pytest

from spm_model.errors import ModelError
from spm_model.methods.smm_parts import fit_codebook, local_features, mask_frame, root_sift


def test_mask_frame():
    mask = np.zeros((20, 30), dtype=bool)
    mask[4:8, 10:20] = True                      # 4 rows x 10 columns
    centroid, scale = mask_frame(mask)
    np.testing.assert_allclose(centroid, [14.5, 5.5])
    assert scale == pytest.approx(np.sqrt(40.0))
    assert mask_frame(np.zeros((5, 5), dtype=bool)) is None


def test_mask_frame_gives_the_floats_of_the_mean_pixel_bit_for_bit():
    rng = np.random.default_rng(0)
    for _ in range(200):
        h, w = rng.integers(1, 400, 2)
        mask = rng.random((h, w)) < rng.random() ** 3
        if not mask.any():
            continue
        rows, cols = np.nonzero(mask)
        centroid, scale = mask_frame(mask.astype(np.uint8) * 255)
        assert centroid.tobytes() == np.array([cols.mean(), rows.mean()]).tobytes()
        assert scale == float(np.sqrt(rows.size))


def test_root_sift_is_unit_and_hellinger():
    rng = np.random.default_rng(0)
    desc = rng.integers(0, 255, (6, 128)).astype(np.float32)
    r = root_sift(desc)
    np.testing.assert_allclose(np.linalg.norm(r, axis=1), 1.0, rtol=1e-5)
    # Dot products of RootSIFT are the Bhattacharyya coefficients of the l1-normalised SIFT.
    p = desc / desc.sum(axis=1, keepdims=True)
    np.testing.assert_allclose(r[0] @ r[1], np.sqrt(p[0] * p[1]).sum(), rtol=1e-5)


def _textured(shift=(0, 0)):
    rng = np.random.default_rng(3)
    patch = (rng.random((12, 12)) * 255).astype(np.uint8)
    patch = np.kron(patch, np.ones((4, 4), dtype=np.uint8))          # 48 x 48 blocky texture
    rgb = np.zeros((128, 128, 3), dtype=np.uint8)
    mask = np.zeros((128, 128), dtype=bool)
    r, c = 30 + shift[0], 40 + shift[1]
    rgb[r:r + 48, c:c + 48] = patch[:, :, None]
    mask[r:r + 48, c:c + 48] = True
    return rgb, mask


def test_local_features_are_object_centred():
    geometry, appearance = local_features(*_textured())
    assert len(geometry) >= 10 and appearance.shape == (len(geometry), 128)
    # Inside the 48 px square around its centre, in units of sqrt(area) = 48 px.
    assert np.abs(geometry).max() <= 0.5 + 1e-9
    moved, moved_app = local_features(*_textured(shift=(10, -20)))
    # Moving the object moves no feature: each one found again at its place, with its
    # descriptor (SIFT's keypoint cap may swap one of equal strength).
    gap = np.linalg.norm(moved[:, None] - geometry[None], axis=2)
    same = gap.min(axis=1) < 1e-3
    assert same.mean() >= 0.95
    # (several orientations may share a place: compare with the closest descriptor there)
    app_gap = np.abs(moved_app[:, None] - appearance[None]).max(axis=2) + np.where(gap < 1e-3, 0.0, np.inf)
    assert np.all(app_gap[same].min(axis=1) < 0.05)
    empty_g, empty_a = local_features(np.zeros((32, 32, 3), np.uint8), np.zeros((32, 32), bool))
    assert empty_g.shape == (0, 2) and empty_a.shape == (0, 128)


def _clusters(seed=0, per=60, noise=1.0):
    """Three known parts: appearance near one of three random unit vectors, geometry near
    one of three places (noise 0: exactly there); returns geometry (3 per, 2),
    appearance (3 per, 128), labels."""
    protos = np.abs(np.random.default_rng(0).normal(size=(3, 128)))
    rng = np.random.default_rng(seed)
    protos /= np.linalg.norm(protos, axis=1, keepdims=True)
    places = np.array([[-0.3, -0.3], [0.3, 0.0], [0.0, 0.35]])
    labels = np.repeat(np.arange(3), per)
    appearance = protos[labels] + rng.normal(scale=0.01 * noise, size=(3 * per, 128))
    geometry = places[labels] + rng.normal(scale=0.02 * noise, size=(3 * per, 2))
    return geometry, appearance, labels


def test_codebook_learns_and_detects_known_parts():
    geometry, appearance, labels = _clusters()
    book = fit_codebook(geometry, appearance, parts=3, dims=4, seed=0)
    # Each learned part is one of the known clusters (one to one).
    d2 = book.mahalanobis(book.joint(geometry, appearance))
    assign = d2.argmin(axis=1)
    mapping = {k: np.bincount(assign[labels == k]).argmax() for k in range(3)}
    assert sorted(mapping.values()) == [0, 1, 2]
    assert all(np.mean(assign[labels == k] == mapping[k]) == 1.0 for k in range(3))
    # An image showing parts 0 and 2 (one feature each, at their centres) detects exactly
    # those, where they are.
    test_g, test_a, _ = _clusters(seed=5, per=1, noise=0.0)
    presence, location = book.detect(test_g[[0, 2]], test_a[[0, 2]])
    assert presence[mapping[0]] and presence[mapping[2]] and not presence[mapping[1]]
    np.testing.assert_allclose(location[mapping[0]], test_g[0])
    np.testing.assert_allclose(location[mapping[2]], test_g[2])
    nothing, where = book.detect(np.zeros((0, 2)), np.zeros((0, 128)))
    assert not nothing.any() and not where.any()


def test_codebook_refuses_too_few_features():
    geometry, appearance, _ = _clusters(per=2)
    with pytest.raises(ModelError, match="at least 20 local features"):
        fit_codebook(geometry, appearance, parts=10)


def test_small_images_are_upsampled_enough_for_sift():
    from spm_model.methods.smm_parts import upsample_factor

    assert [upsample_factor((s, s, 3)) for s in (32, 64, 99, 100, 128, 199, 200, 640)] == [7, 4, 3, 2, 2, 2, 1, 1]
    rgb, mask = _textured()
    small = cv2.resize(rgb, (32, 32), interpolation=cv2.INTER_AREA)
    small_mask = cv2.resize(mask.astype(np.uint8), (32, 32), interpolation=cv2.INTER_NEAREST) > 0
    geometry, _ = local_features(small, small_mask)
    assert len(geometry) >= 30                         # 36 here; doubling alone (64 px) found 21
    assert np.abs(geometry).max() <= 0.6               # still object-centred, in units of sqrt(area)


@pytest.mark.parametrize("n, d, k, seed", [(3000, 18, 96, 0), (500, 5, 7, 3), (40, 2, 40, 1)])
def test_kmeans_plus_plus_seeds_are_scipys_bit_for_bit(n, d, k, seed):
    import warnings

    from scipy.cluster.vq import kmeans2

    from spm_model.methods.smm_parts import kmeans_plus_plus

    data = np.random.default_rng(seed + 10).normal(size=(n, d))
    data[: n // 10] = data[0]                                      # repeated points: zero distances
    seeds = kmeans_plus_plus(data, k, np.random.default_rng(seed))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")                             # scipy's warning of an empty cluster
        theirs = kmeans2(data, k, minit="++", seed=np.random.default_rng(seed), iter=5)
        ours = kmeans2(data, seeds, minit="matrix", iter=5)
    assert np.array_equal(theirs[0], ours[0]) and np.array_equal(theirs[1], ours[1])

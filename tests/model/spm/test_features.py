"""spm_model.spm.features: SIFT keypoints to the manifold vector, raw vectors, path neighbours, and the
feature options."""

import numpy as np
import pytest

from spm_data.io.shards import read_shard
from spm_model.bench.feature_cache import find_shards
from spm_model.spm.features import FeatureConfig, FeatureError, image_features


def test_image_features_on_a_render_and_errors(model_shards):
    d = read_shard(find_shards(model_shards)[0], ["rgb", "mask"], frames=slice(0, 1))
    f = image_features(d["rgb"][0], d["mask"][0])
    assert f["vector"].shape == (16,) and np.isclose(np.linalg.norm(f["vector"]), 1.0)
    assert 0 <= f["eccentricity"] < 1 and f["keypoints"] >= 16
    with pytest.raises(FeatureError, match="SIFT found 0 keypoints, need at least 16"):
        image_features(np.zeros((64, 64, 3), np.uint8))
    with pytest.raises(FeatureError, match=r"expected an \(H, W, 3\) uint8"):
        image_features(np.zeros((64, 64), np.uint8))


def test_feature_config_vector_options():
    from spm_model.spm.features import manifold_from_keypoints

    default = FeatureConfig()
    assert (default.order, default.normalise, default.append_ellipse, default.dims) == ("sign", True, False, 16)
    assert FeatureConfig(append_ellipse=True).dims == 19
    with pytest.raises(FeatureError, match="order must be"):
        FeatureConfig(order="random")
    pts = np.random.default_rng(0).uniform(0, 100, (60, 2))
    v, _ = manifold_from_keypoints(pts, FeatureConfig(ellipse="direct"))
    raw, _ = manifold_from_keypoints(pts, FeatureConfig(ellipse="direct", normalise=False))
    np.testing.assert_allclose(np.linalg.norm(v), 1.0)
    np.testing.assert_allclose(raw / np.linalg.norm(raw), v)
    by_angle, _ = manifold_from_keypoints(pts, FeatureConfig(ellipse="direct", order="angle"))
    np.testing.assert_allclose(np.sort(by_angle), np.sort(v))  # the same values, another order
    extra, _ = manifold_from_keypoints(pts, FeatureConfig(ellipse="direct", append_ellipse=True))
    assert extra.shape == (19,) and np.array_equal(extra[:16], v)


def test_small_images_are_upsampled_for_sift_and_large_ones_downscaled():
    from spm_model.spm.features import working_image

    rgb, mask = np.zeros((32, 48, 3), np.uint8), np.zeros((32, 48), np.uint8)
    rgb[8:24, 10:30], mask[8:24, 10:30] = 200, 1
    up, up_mask = working_image(rgb, mask, max_side=256, min_side=128)
    assert up.shape == (128, 192, 3) and up_mask.shape == (128, 192) and set(np.unique(up_mask)) == {0, 1}
    same, _ = working_image(np.zeros((128, 128, 3), np.uint8), None, 256, 128)
    assert same.shape == (128, 128, 3)                          # the default renders: untouched
    down, _ = working_image(np.zeros((512, 256, 3), np.uint8), None, 256, 128)
    assert down.shape == (256, 128, 3)
    with pytest.raises(FeatureError, match="min_side must be in 1..max_side"):
        FeatureConfig(min_side=512)


def test_a_32_pixel_image_gets_spm_features_once_upsampled(model_shards):
    """A render downscaled to 32 px: SIFT on it as it is finds too few keypoints for the
    ellipse; upsampled to 128 px (the default min_side) it finds enough."""
    import cv2

    d = read_shard(find_shards(model_shards)[0], frames=slice(0, 6))
    got = []
    for side in (1, 128):
        config = FeatureConfig(ellipse="direct", min_side=side)
        found = 0
        for rgb, mask in zip(d["rgb"], d["mask"]):
            small = cv2.resize(rgb, (32, 32), interpolation=cv2.INTER_AREA)
            small_mask = cv2.resize(mask, (32, 32), interpolation=cv2.INTER_NEAREST)
            try:
                image_features(small, small_mask, config)
                found += 1
            except FeatureError:
                pass
        got.append(found)
    assert got[0] < got[1] and got[1] >= 4, got


def test_upsampling_stops_at_max_side():
    from spm_model.spm.features import working_image

    up, _ = working_image(np.zeros((100, 250, 3), np.uint8), None, max_side=256, min_side=128)
    assert up.shape == (102, 256, 3)

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

"""spm_model.spm.estimator: SPMEstimator fits, saves and loads as one file, and keeps pose information
through its projection and regressor."""

import numpy as np
import pytest

from spm_model.bench.feature_cache import load_features
from spm_model.spm.estimator import ModelError, SPMEstimator
from spm_model.spm.features import FeatureConfig
from spm_model.bench.metrics import pose_errors, summarise

FAST = FeatureConfig(ellipse="direct")


@pytest.fixture(scope="module")
def table(model_shards):
    return load_features(model_shards, FAST)


def usable(table):
    ok = np.isfinite(table.train_vector).all(axis=1)
    return table.train_vector[ok], table.pose[ok]


def test_estimator_fits_saves_and_loads_as_one_file(table, tmp_path):
    X, y = usable(table)
    model = SPMEstimator(features=FAST, projection_samples=60)
    assert not hasattr(model, "regressor_") and model.projection_samples == 60
    assert model.fit(X, y) is model
    fit = summarise(pose_errors(model.predict(X), y))
    assert fit["geodesic_median_deg"] < 10          # it represents its training set
    path = model.save(tmp_path / "m.npz")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.npz"]
    loaded = SPMEstimator.load(path)
    assert loaded.features == FAST and loaded.projection_samples == 60
    assert np.array_equal(loaded.predict(X), model.predict(X))
    with pytest.raises(ModelError, match=r"expected features of shape \(n, 16\)"):
        model.predict(X[:, :8])
    with pytest.raises(ModelError, match=r"^this SPMEstimator is not fitted yet; call fit\(X, y\) first, "
                                         r"or load a model file with SPMEstimator\.load\(path\)$"):
        SPMEstimator().predict(X)
    # A model file from before FeatureConfig.min_side: its features were made without upsampling.
    from spm_model.base.model_files import load_model_file

    header, arrays = load_model_file(path, "spm")
    del header["features"]["min_side"]
    assert SPMEstimator.from_model_file(header, arrays).features.min_side == 1
    (tmp_path / "junk.npz").write_bytes(b"junk")
    with pytest.raises(ModelError, match="not an spm model file"):
        SPMEstimator.load(tmp_path / "junk.npz")


def test_projection_and_regressor_keep_pose_information():
    """Vectors that are a smooth function of the pose (as SPM assumes its manifold
    is): held-out poses are recovered, across the +-180 degree wrap."""
    rng = np.random.default_rng(0)
    az = rng.uniform(0, 360, 600)
    el = rng.uniform(0, 60, 600)
    a, e = np.radians(az), np.radians(el)
    basis = rng.normal(size=(5, 16))
    X = np.abs(np.column_stack([np.cos(a), np.sin(a), np.cos(e), np.sin(e), np.ones_like(a)]) @ basis) + 0.5
    X /= np.linalg.norm(X, axis=1, keepdims=True)
    y = np.column_stack([90 + el, np.zeros_like(el), (-(az + 90) + 180) % 360 - 180, np.zeros((600, 2)),
                         np.full(600, 0.7)])
    model = SPMEstimator(features=FAST, noise=0.001).fit(X[:500], y[:500])
    s = summarise(pose_errors(model.predict(X[500:]), y[500:]))
    assert s["geodesic_median_deg"] < 3 and s["success_tol5"] > 60, s
    shuffled = SPMEstimator(features=FAST).fit(X[:500], y[rng.permutation(500)])
    assert summarise(pose_errors(shuffled.predict(X[500:]), y[500:]))["geodesic_median_deg"] > 30

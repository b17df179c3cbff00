"""spm_model.methods.baselines: KNN averages angles on the circle; PCA and least squares on raw vectors;
chance is a seeded training pose."""

import numpy as np
import pytest

from spm_model.errors import ModelError
from spm_model.methods.baselines import ChancePose, KNNPose, LSPose, PCAPose, RawImagePose
from tests.helpers import N, frames, labels


def test_knn_averages_angles_on_the_circle():
    X = np.array([[0.0], [1.0], [2.0], [10.0]])
    y = np.zeros((4, 6))
    y[:, 2] = [179, -179, 177, 0]
    y[:, 5] = [0.6, 0.7, 0.8, 0.0]
    one = KNNPose(k=1).fit(X, y).predict(np.array([[0.9]]))
    three = KNNPose(k=3).fit(X, y).predict(np.array([[1.0]]))
    assert np.isclose(one[0, 2], -179)
    assert np.isclose(abs(three[0, 2]), 179, atol=0.01) and np.isclose(three[0, 5], 0.7)  # not (179-179+177)/3


def test_pca_and_ls_baselines_on_raw_vectors():
    rng = np.random.default_rng(0)
    angles = np.arange(0, 360, 10.0)
    basis = rng.normal(size=(3, 64))
    raw = np.clip(128 + 40 * (np.cos(np.radians(angles))[:, None] * basis[0]
                              + np.sin(np.radians(angles))[:, None] * basis[1]), 0, 255)
    y = np.zeros((len(angles), 6))
    y[:, 2] = (angles + 180) % 360 - 180
    pca = PCAPose(components=4).fit(raw, y)
    assert np.allclose(pca.predict(raw)[:, 2], y[:, 2])        # a training image finds itself
    ls = LSPose(alpha=1e-3).fit(raw, y)
    err = np.abs((ls.predict(raw)[:, 2] - y[:, 2] + 180) % 360 - 180)
    assert np.median(err) < 5



def test_chance_is_a_seeded_training_pose_and_raw_kind_is_checked():
    f, poses = frames(N, 0), labels(N, 0)
    pred = ChancePose(seed=5).fit(f, poses).predict(frames(7, 1))
    assert pred.shape == (7, 6) and all(any(np.array_equal(p, q) for q in poses) for p in pred)
    np.testing.assert_array_equal(ChancePose(seed=5).fit(f, poses).predict(frames(7, 2)), pred)
    with pytest.raises(ModelError, match="^kind must be 'pca' or 'ls', got 'svm'$"):
        RawImagePose(kind="svm").fit(f, poses)

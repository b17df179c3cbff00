"""spm_model.methods: the built-in methods behind one interface, a user's estimator by
MODULE:CLASS, and predictions checked for shape (frames from cached columns: no rendering)."""

import textwrap

import numpy as np
import pytest

from spm_model.features import FeatureConfig
from spm_model.fitted import ModelError
from spm_model.methods import (METHOD_NAMES, ChancePose, RawImagePose, SPMNeighbours, SPMPose, builtin_methods,
                               check_predictions, load_estimator_class)
from tests.helpers import FAST_SPM, N, frames, labels


def test_builtin_methods_in_report_order_knn_sharing_the_spm_model():
    features = FeatureConfig(ellipse="direct")
    methods = builtin_methods(3, features, {"projection_samples": 16})
    assert list(methods) == ["spm", "knn1", "knn3", "pca", "ls", "template", "chance"] == list(METHOD_NAMES)
    spm = methods["spm"]
    assert spm.seed == 3 and spm.features == features and spm.params == {"projection_samples": 16}
    assert methods["knn1"].spm is spm and methods["knn3"].spm is spm and methods["knn3"].k == 3
    assert (methods["pca"].kind, methods["ls"].kind, methods["chance"].seed) == ("pca", "ls", 3)


def test_spm_pose_needs_features_on_ten_frames_and_gives_nan_without_one():
    f, poses = frames(N, 0), labels(N, 0)
    vectors = f.columns["train_vector"].copy()
    vectors[3:] = np.nan                                 # only 3 frames with a feature
    few = type(f)({**f.columns, "train_vector": vectors})
    with pytest.raises(ModelError, match=r"^only 3 training frames have SPM features \(need 10\)"):
        SPMPose(params=FAST_SPM).fit(few, poses)
    model = SPMPose(params=FAST_SPM).fit(f, poses)
    query = f.columns["query_vector"].copy()
    query[[1, 4]] = np.nan
    pred = model.predict(type(f)({**f.columns, "query_vector": query}))
    assert np.isnan(pred[[1, 4]]).all() and np.isfinite(np.delete(pred, [1, 4], axis=0)).all()
    knn = SPMNeighbours(k=1, spm=model).fit(f, poses)
    assert knn.spm_ is model                              # an SPM fitted already is reused, not refitted


def test_chance_is_a_seeded_training_pose_and_raw_kind_is_checked():
    f, poses = frames(N, 0), labels(N, 0)
    pred = ChancePose(seed=5).fit(f, poses).predict(frames(7, 1))
    assert pred.shape == (7, 6) and all(any(np.array_equal(p, q) for q in poses) for p in pred)
    np.testing.assert_array_equal(ChancePose(seed=5).fit(f, poses).predict(frames(7, 2)), pred)
    with pytest.raises(ModelError, match="^kind must be 'pca' or 'ls', got 'svm'$"):
        RawImagePose(kind="svm").fit(f, poses)


def test_load_estimator_class(tmp_path, monkeypatch):
    (tmp_path / "mine.py").write_text(textwrap.dedent('''
        class Good:
            def fit(self, frames, poses):
                return self

            def predict(self, frames):
                return None

        class NoPredict:
            def fit(self, frames, poses):
                return self

        VALUE = 3
        '''))
    (tmp_path / "broken.py").write_text("raise RuntimeError('no GPU here')\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    assert load_estimator_class("mine:Good").__name__ == "Good"
    for spec, message in [
        ("mine", "--estimator expects MODULE:CLASS (for example my_pose:MyEstimator), got 'mine'"),
        ("mine:Good:x", "--estimator expects MODULE:CLASS (for example my_pose:MyEstimator), got 'mine:Good:x'"),
        ("nowhere:X", "--estimator nowhere:X: cannot import nowhere (ModuleNotFoundError: No module named "
                      "'nowhere'); is its folder on PYTHONPATH?"),
        ("broken:X", "--estimator broken:X: cannot import broken (RuntimeError: no GPU here); is its folder on "
                     "PYTHONPATH?"),
        ("mine:NoPredict", "--estimator mine:NoPredict: NoPredict is not a class in mine with fit(frames, poses) "
                           "and predict(frames)"),
        ("mine:VALUE", "--estimator mine:VALUE: VALUE is not a class in mine with fit(frames, poses) and "
                       "predict(frames)"),
    ]:
        with pytest.raises(ModelError) as info:
            load_estimator_class(spec)
        assert str(info.value) == message


def test_check_predictions():
    out = check_predictions("mine", [[0, 0, 0, 0, 0, 1]] * 2, 2)
    assert out.dtype == np.float64 and out.shape == (2, 6)
    for pred, got in [(np.zeros((3, 6)), "shape (3, 6)"), (np.zeros((2, 5)), "shape (2, 5)"),
                      (None, "shape ()"), ([[1, 2], [3]], "something that is not an array")]:
        with pytest.raises(ModelError) as info:
            check_predictions("mine", pred, 2)
        assert str(info.value) == ("estimator mine: predict(frames) must return (2, 6) labels (rx, ry, rz degrees, "
                                   f"t metres; NaN rows for no estimate), got {got}")

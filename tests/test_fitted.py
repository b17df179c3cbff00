"""One fitted check for every estimator (spm_model/fitted.py), and model files that
restore state through the classes' public ``from_state``: synthetic inputs only
(frames served from cached feature columns), so no rendering."""

import json
import zipfile

import numpy as np
import pytest

from spm_model.baselines import KNNPose, LSPose, PCAPose
from spm_model.estimator import ModelError, SPMEstimator
from spm_model.model_files import load_model_file
from spm_model.fitted import check_fitted, is_fitted
from spm_model.methods import ChancePose, RawImagePose, SPMNeighbours, SPMPose
from spm_model.regressor import RBFPoseRegressor
from spm_model.descriptors import HOG_SIZE
from spm_model.template import TemplatePose
from spm_model.train import load_model

N = 24


class CachedFrames(list):
    """Frames whose features are all cached (as spm_model.frames.Frames serves them)."""

    def __init__(self, columns: dict):
        super().__init__({"K": k} for k in columns["K"])
        self.columns = columns

    def column(self, name):
        return self.columns.get(name)


def labels(n, seed):
    rng = np.random.default_rng(seed)
    return np.column_stack([rng.uniform(-180, 180, (n, 3)), rng.normal(0, 0.05, (n, 2)), rng.uniform(0.5, 1, n)])


def vectors(n, seed, d=16):
    x = np.abs(np.random.default_rng(seed).normal(size=(n, d))) + 0.1
    return x / np.linalg.norm(x, axis=1, keepdims=True)


def frames(n, seed):
    rng = np.random.default_rng(seed)
    K = np.tile(np.array([[60.0, 0, 31.5], [0, 60, 31.5], [0, 0, 1]]), (n, 1, 1))
    geometry = np.column_stack([rng.uniform(20, 40, (n, 2)), rng.uniform(10, 50, n), K[:, 0, 0], K[:, 1, 1],
                                K[:, 0, 2], K[:, 1, 2]])
    template = np.hstack([rng.uniform(0, 1, (n, HOG_SIZE)), geometry]).astype(np.float32)
    return CachedFrames({"train_vector": vectors(n, seed), "query_vector": vectors(n, seed + 1),
                         "raw": rng.integers(0, 255, (n, 64)).astype(np.uint8), "template": template, "K": K})


FAST_SPM = {"projection_samples": 16, "projection": "knn", "neighbours": 8}

def rows(d):
    return lambda seed: vectors(N, seed, d)


def frame_rows(seed):
    return frames(N, seed)


# name: (an unfitted instance, input of N rows for a seed, the fit call its message names)
CASES = {
    "RBFPoseRegressor": (lambda: RBFPoseRegressor(), rows(4), "fit(X, y)"),
    "KNNPose": (lambda: KNNPose(k=3), rows(4), "fit(X, y)"),
    "PCAPose": (lambda: PCAPose(components=4), rows(32), "fit(raw, y)"),
    "LSPose": (lambda: LSPose(), rows(32), "fit(raw, y)"),
    "SPMEstimator": (lambda: SPMEstimator(**FAST_SPM), rows(16), "fit(X, y)"),
    "TemplatePose": (lambda: TemplatePose(components=8), frame_rows, "fit(frames, poses)"),
    "SPMPose": (lambda: SPMPose(params=FAST_SPM), frame_rows, "fit(frames, poses)"),
    "SPMNeighbours": (lambda: SPMNeighbours(k=3, spm=SPMPose(params=FAST_SPM)), frame_rows, "fit(frames, poses)"),
    "RawImagePose": (lambda: RawImagePose(kind="ls"), frame_rows, "fit(frames, poses)"),
    "ChancePose": (lambda: ChancePose(seed=3), frame_rows, "fit(frames, poses)"),
}
LOADABLE = {"SPMEstimator", "TemplatePose"}


def unfitted_message(name):
    fix = CASES[name][2] + " first" + (f", or load a model file with {name}.load(path)" if name in LOADABLE else "")
    return f"this {name} is not fitted yet; call {fix}"


@pytest.mark.parametrize("name", sorted(CASES))
def test_every_estimator_refuses_to_predict_unfitted_with_the_same_error(name):
    make, data, _ = CASES[name]
    model = make()
    with pytest.raises(ModelError) as info:
        model.predict(data(1))
    assert str(info.value) == unfitted_message(name)
    for method in ("transform", "save", "predict_image", "check_loaded"):
        if hasattr(model, method):
            with pytest.raises(ModelError) as info:
                getattr(model, method)(*(() if method == "check_loaded" else (None,)))
            assert str(info.value) == unfitted_message(name), method


@pytest.mark.parametrize("name", sorted(CASES))
def test_every_estimator_keeps_parameters_and_learned_state_apart(name):
    make, data, _ = CASES[name]
    model = make()
    params = dict(vars(model))
    assert not [k for k in params if k.endswith("_")] and not is_fitted(model, type(model).FITTED)
    with pytest.raises(TypeError):
        type(model)(1)                                    # keyword-only parameters
    assert model.fit(data(0), labels(N, 0)) is model
    learned = sorted(k for k in vars(model) if k.endswith("_"))
    assert learned == sorted(type(model).FITTED) and is_fitted(model, type(model).FITTED)
    assert {k: v for k, v in vars(model).items() if not k.endswith("_")} == params  # fit changes no parameter
    pred = model.predict(data(5))
    assert pred.shape == (N, 6) and np.isfinite(pred).all()


def test_a_partly_fitted_estimator_names_what_is_missing():
    model = KNNPose().fit(vectors(N, 0, 3), labels(N, 0))
    del model.y_
    with pytest.raises(ModelError) as info:
        model.predict(vectors(2, 1, 3))
    assert str(info.value) == "this KNNPose is not fitted yet (y_ not set); call fit(X, y) first"

    class Plain:                                          # any class: the message reads its fit's signature
        def fit(self, images, labels):
            return self

    with pytest.raises(ModelError, match=r"^this Plain is not fitted yet; call fit\(images, labels\) first$"):
        check_fitted(Plain(), ("w_",))
    check_fitted(Plain(), ())                             # nothing learned: always fitted


def members(path):
    with zipfile.ZipFile(path) as z:
        return [(n, z.read(n)) for n in z.namelist()]


def test_spm_model_file_round_trips_through_from_state(tmp_path):
    X, y = vectors(N, 0), labels(N, 0)
    model = SPMEstimator(**FAST_SPM, landmarks=10, noise_copies=2).fit(X, y)
    path = model.save(tmp_path / "model.npz")
    header, arrays = load_model_file(path, "spm")
    assert list(arrays) == ["W", "centres", "dual_coef", "mean"]
    assert np.array_equal(arrays["W"], model.projection_.W)
    assert np.array_equal(arrays["centres"], model.regressor_.X_fit_)
    assert np.array_equal(arrays["dual_coef"], model.regressor_.dual_coef_)
    assert np.array_equal(arrays["mean"], model.regressor_.mean_) and header["gamma_"] == model.regressor_.gamma_
    assert header["params"] == {k: v for k, v in model.get_params().items() if k != "features"}
    loaded = SPMEstimator.load(path)
    assert loaded.get_params() == model.get_params() and loaded.regressor_.landmarks == 10
    assert np.array_equal(loaded.predict(X), model.predict(X))
    assert np.array_equal(loaded.transform(X), model.transform(X))
    assert members(loaded.save(tmp_path / "again.npz")) == members(path)       # byte-identical arrays and header
    rebuilt = SPMEstimator.from_state(projection_=model.projection_, regressor_=model.regressor_, **model.get_params())
    assert np.array_equal(rebuilt.predict(X), model.predict(X))


def test_regressor_from_state_predicts_as_the_fitted_one():
    X, y = vectors(N, 0, 4), labels(N, 0)
    model = RBFPoseRegressor(alpha=0.01, noise=0.01, noise_copies=1).fit(X, y)
    state = {k: getattr(model, k) for k in RBFPoseRegressor.FITTED}
    rebuilt = RBFPoseRegressor.from_state(**state, alpha=0.01, noise=0.01, noise_copies=1)
    assert rebuilt.alpha == 0.01 and rebuilt.X_fit_ is model.X_fit_
    assert np.array_equal(rebuilt.predict(vectors(5, 1, 4)), model.predict(vectors(5, 1, 4)))
    with pytest.raises(TypeError):
        RBFPoseRegressor.from_state(**{k: v for k, v in state.items() if k != "mean_"})


def test_template_model_file_round_trips_and_names_a_missing_array(tmp_path):
    f, poses = frames(N, 0), labels(N, 0)
    model = TemplatePose(components=8, size_neighbours=5).fit(f, poses)
    path = model.save(tmp_path / "reference-model.npz")
    header, arrays = load_model_file(path, "template")
    assert header["params"] == {"components": 8, "size_neighbours": 5, "ray_correction": False}
    assert list(arrays) == [k[:-1] for k in TemplatePose.FITTED]
    assert all(np.array_equal(arrays[k[:-1]], getattr(model, k)) for k in TemplatePose.FITTED)
    loaded = TemplatePose.load(path)
    assert loaded.size_neighbours == 5 and np.array_equal(loaded.predict(frames(N, 5)), model.predict(frames(N, 5)))
    assert members(loaded.save(tmp_path / "again.npz")) == members(path)
    del arrays["codes"]
    np.savez(tmp_path / "hollow.npz", header=np.array(json.dumps(header)), **arrays)
    with pytest.raises(ModelError) as info:
        load_model(tmp_path / "hollow.npz")
    assert str(info.value) == (f"{tmp_path / 'hollow.npz'}: damaged spm model file (no 'codes' in it); "
                               "retrain it with spm train")

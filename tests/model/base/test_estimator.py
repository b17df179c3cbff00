"""One fitted check for every estimator (spm_model/base/estimator.py): synthetic inputs only (frames
served from cached feature columns, tests.helpers), so no rendering. Model files that restore
state through ``from_state``: tests/model/base/test_model_files.py."""

import numpy as np
import pytest

from spm_model.methods.baselines import KNNPose, LSPose, PCAPose
from spm_model.spm.estimator import ModelError, SPMEstimator
from spm_model.base.estimator import check_fitted, is_fitted
from spm_model.methods.registry import ChancePose, RawImagePose, SPMNeighbours, SPMPose
from spm_model.spm.regressor import RBFPoseRegressor
from spm_model.methods.template import TemplatePose
from tests.helpers import FAST_SPM, N, frames, labels, vectors


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

"""spm_model.base.model_files: model files that restore state through the classes' public
``from_state`` (byte-identical when saved again), and a damaged one named in one line."""

import json
import zipfile

import numpy as np
import pytest

from spm_model.spm.estimator import ModelError, SPMEstimator
from spm_model.base.model_files import load_model_file
from spm_model.methods.template import TemplatePose
from spm_model.commands.evaluate import load_model
from tests.helpers import FAST_SPM, N, frames, labels, vectors


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
    assert np.array_equal(arrays["mean"], model.regressor_.mean_) and header["gamma_"] == model.regressor_.kernel_coef_
    assert header["params"] == {k: v for k, v in model.get_params().items() if k != "features"}
    loaded = SPMEstimator.load(path)
    assert loaded.get_params() == model.get_params() and loaded.regressor_.landmarks == 10
    assert np.array_equal(loaded.predict(X), model.predict(X))
    assert np.array_equal(loaded.transform(X), model.transform(X))
    assert members(loaded.save(tmp_path / "again.npz")) == members(path)       # byte-identical arrays and header
    rebuilt = SPMEstimator.from_state(projection_=model.projection_, regressor_=model.regressor_, **model.get_params())
    assert np.array_equal(rebuilt.predict(X), model.predict(X))


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

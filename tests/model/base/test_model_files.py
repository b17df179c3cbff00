"""spm_model.base.model_files: model files that restore state through the classes' public
``from_state`` (byte-identical when saved again), and a damaged one named in one line."""

import zipfile

import numpy as np
import pytest

from spm_model.spm.estimator import ModelError, SPMEstimator
from spm_model.base.model_files import load_model_file
from spm_model.methods.template import TemplatePose
from spm_model.pipelines.evaluate import load_model
from tests.helpers import FAST_SPM, N, frames, labels, sealed_model, vectors


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
    sealed_model(tmp_path / "hollow.npz", header, arrays)
    with pytest.raises(ModelError) as info:
        load_model(tmp_path / "hollow.npz")
    assert str(info.value) == (f"{tmp_path / 'hollow.npz'}: damaged spm model file (no 'codes' in it); "
                               "retrain it with spm train")


def test_no_flipped_byte_of_a_model_file_is_ever_used(tmp_path):
    """A bit flipped anywhere (every 11th byte, and every byte of the first 600: zip headers and
    spm's JSON header) is refused with one ModelError, or leaves the model exactly as written
    (a byte zip ignores, such as a timestamp): never a different model, never another error."""
    model = SPMEstimator(**FAST_SPM).fit(vectors(40, 0), labels(40, 0))
    path = model.save(tmp_path / "model.npz")
    good = path.read_bytes()
    reference = load_model_file(path, "spm")
    refused = same = 0
    for i in sorted(set(range(0, len(good), 11)) | set(range(min(600, len(good))))):
        bad = bytearray(good)
        bad[i] ^= 1 << (i % 8)
        path.write_bytes(bytes(bad))
        try:
            header, arrays = load_model_file(path, "spm")
        except ModelError:
            refused += 1
            continue
        assert header == reference[0] and all(np.array_equal(arrays[k], reference[1][k]) for k in reference[1]), i
        same += 1
    assert refused > 0.9 * (refused + same)

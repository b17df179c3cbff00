"""spm_model.methods.registry: the built-in methods behind one interface, a user's estimator by
MODULE:CLASS, and predictions checked for shape (frames from cached columns: no rendering)."""

import textwrap

import numpy as np
import pytest

from spm_model.errors import ModelError
from spm_model.base.estimator import Needs, needs_of
from spm_model.methods.registry import (METHOD_NAMES, METHODS, SAVED_MODELS, builtin_methods, check_method_names,
                                        check_predictions, load_estimator_class)
from spm_model.spm.features import FeatureConfig


def test_builtin_methods_in_report_order_knn_sharing_the_spm_model():
    features = FeatureConfig(ellipse="direct")
    methods = builtin_methods(3, features, {"projection_samples": 16})
    assert list(methods) == ["spm", "knn1", "knn3", "pca", "ls", "n3m", "sift-pnp", "smm", "template",
                             "cnn", "chance"] == list(METHOD_NAMES)
    spm = methods["spm"]
    assert spm.seed == 3 and spm.features == features and spm.params == {"projection_samples": 16}
    assert methods["knn1"].spm is spm and methods["knn3"].spm is spm and methods["knn3"].k == 3
    assert (methods["pca"].kind, methods["ls"].kind, methods["chance"].seed) == ("pca", "ls", 3)
    assert methods["cnn"].seed == 3 and type(methods["cnn"]).DETERMINISTIC is False   # seeded: fitted every run


def test_n3m_is_the_papers_method_and_sift_pnp_its_fallback_alone_each_named_for_it():
    methods = builtin_methods(0, FeatureConfig(ellipse="direct"))
    n3m, sift_pnp = methods["n3m"], methods["sift-pnp"]
    assert type(n3m).__name__ == "N3MPose" and n3m.ransac_fallback is False
    assert type(sift_pnp).__name__ == "SiftPnPPose"
    for method in (n3m, sift_pnp):
        assert needs_of(method) == Needs(frames=2, depth=True) and type(method).DETERMINISTIC is True
    assert METHOD_NAMES["n3m"] == "N3M (Hinterstoisser et al. 2007; marker levels only)"
    assert METHOD_NAMES["sift-pnp"] == "SIFT + PnP (all matches; not in a paper)"


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


def test_every_list_of_methods_is_read_from_the_rows():
    assert list(METHOD_NAMES) == [m.name for m in METHODS] == list(builtin_methods(0, FeatureConfig()))
    assert {n: m.model_file for n, m in SAVED_MODELS.items()} == {
        "spm": "model.npz", "template": "reference-model.npz", "cnn": "cnn-model.npz"}
    assert [m.model_class().__name__ for m in SAVED_MODELS.values()] == ["SPMEstimator", "TemplatePose", "CNNPose"]


def test_unknown_method_names_are_one_line_errors_with_the_choices():
    assert check_method_names(None) is None and check_method_names(["knn1", "chance"]) == ["knn1", "chance"]
    with pytest.raises(ModelError, match=r"^builtins: unknown spn; choose from spm, knn1, .*, chance$"):
        check_method_names(["spn"])
    with pytest.raises(ModelError, match="^--methods: unknown empty list; "):
        check_method_names([], "--methods")


def test_train_refuses_an_unknown_builtin_before_any_work(tmp_path):
    from spm_model.pipelines.train import train

    with pytest.raises(ModelError, match="^builtins: unknown spn; choose from "):
        train(tmp_path, tmp_path / "report", builtins=["spn"])
    assert not (tmp_path / "report").exists()


def test_the_cnn_entry_of_the_model_params_goes_to_the_cnn_alone():
    params = {"cnn": {"device": "cpu"}, "alpha": 0.01}
    methods = builtin_methods(3, FeatureConfig(), params)
    assert (methods["cnn"].device, methods["cnn"].seed, methods["spm"].params) == ("cpu", 3, {"alpha": 0.01})
    assert builtin_methods(0, FeatureConfig(), None)["cnn"].device == "auto"
    assert params == {"cnn": {"device": "cpu"}, "alpha": 0.01}   # the caller's kept

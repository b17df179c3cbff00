"""spm_model.bench.final_models: the saved models are fitted as the splits make their methods, saved by
their own save(), and a method added as one registry row with a model file (its module here, a
test-only one) is fitted, saved by `spm train` and read back by `spm evaluate` and `spm predict`
with no other code touched: adding a built-in method that saves a model is 2 places."""

import json
import shutil

import numpy as np
import pytest
from click.testing import CliRunner
from PIL import Image

from cli import model_cli
from spm_data.io.shards import list_shards, read_shard
from spm_model.base.model_files import load_model_file, need, save_model_file
from spm_model.bench.feature_cache import load_features
from spm_model.bench.final_models import fit_final_models, save_final_models, saved_names, training_costs
from spm_model.bench.protocols import final_rows
from spm_model.methods import registry
from spm_model.methods.template import TemplatePose
from spm_model.spm.estimator import SPMEstimator
from spm_model.spm.features import FeatureConfig

FAST = FeatureConfig(ellipse="direct")


def test_the_saved_methods_are_read_from_the_rows_in_report_order():
    assert saved_names(None) == ("spm", "template", "cnn")
    assert saved_names(["pca", "cnn", "template"]) == ("template", "cnn")
    assert saved_names(["pca"]) == ()


def test_the_final_spm_model_is_the_one_fitted_on_every_training_vector(model_shards):
    """The final SPM is made as a split makes it (SPMPose, seed 0) and fitted on the frames: its
    estimator holds the arrays of SPMEstimator fitted on the training vectors directly (model.npz
    unchanged by the move to the rows)."""
    table = load_features(model_shards, FAST)
    rows = final_rows(table, train_occluded=True)
    fitted, declined = fit_final_models(table, {"features": FAST}, rows, ["spm"])
    usable = rows[np.isfinite(table.train_vector[rows]).all(axis=1)]
    direct = SPMEstimator(features=FAST).fit(table.train_vector[usable], table.pose[usable])
    assert declined == {} and list(fitted) == ["spm"] and (len(usable), len(rows)) == (142, 144)   # 2 featureless
    assert np.array_equal(fitted["spm"].model_.projection_.W, direct.projection_.W)
    assert np.array_equal(fitted["spm"].model_.regressor_.dual_coef_, direct.regressor_.dual_coef_)
    assert training_costs(fitted) == {}


def test_a_final_model_that_cannot_be_fitted_is_declined_with_why_and_the_others_are_fitted(model_shards,
                                                                                            monkeypatch):
    def boom(self, frames, poses):
        raise RuntimeError("boom")

    monkeypatch.setattr(TemplatePose, "fit", boom)
    table = load_features(model_shards, FAST)
    rows = final_rows(table, train_occluded=True)[:4]
    featured = int(np.isfinite(table.train_vector[rows]).all(axis=1).sum())
    fitted, declined = fit_final_models(table, {"features": FAST}, rows, ["spm", "template", "chance"])
    assert fitted == {"spm": None, "template": None, "chance": fitted["chance"]} and fitted["chance"] is not None
    assert declined == {"spm": f"needs 10 training frames with SPM features, {featured} of 4 have them (SIFT finds "
                                "too few keypoints on small or plain images)", "template": "RuntimeError: boom"}


def test_saving_writes_each_fitted_model_to_its_rows_file_and_removes_stale_ones(model_shards, tmp_path):
    table = load_features(model_shards, FAST)
    fitted, _ = fit_final_models(table, {"features": FAST}, final_rows(table, True), ["spm"])
    for stale in ("reference-model.npz", "cnn-model.npz", "cnn-model.safetensors"):
        (tmp_path / stale).write_bytes(b"an earlier run's")
    assert save_final_models({**fitted, "template": None}, tmp_path) == {"spm": tmp_path / "model.npz"}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["model.npz"]
    assert load_model_file(tmp_path / "model.npz", "spm")[0]["params"]["seed"] == 0


class MeanPose:
    """A test-only built-in method whose model spm train saves: the training poses' mean, whatever the image."""

    def fit(self, frames, poses):
        self.pose_ = np.asarray(poses, dtype=np.float64).mean(axis=0)
        return self

    def predict(self, frames):
        return np.tile(self.pose_, (len(frames), 1))

    def predict_image(self, rgb, mask=None):
        return {"pose": self.pose_}

    def save(self, path):
        return save_model_file(path, "mean", {}, {"pose": self.pose_})

    @classmethod
    def from_model_file(cls, header, arrays):
        model = cls()
        model.pose_ = arrays["pose"]
        return model

    def check_loaded(self):
        need(self.pose_.shape == (6,), f"pose {self.pose_.shape}, expected (6,)")


@pytest.fixture
def mean_row(monkeypatch):
    """MeanPose's row added to the registry, as a new line in METHODS would add it (the derived
    tables extended in place, as they are built from METHODS when the registry is imported)."""
    row = registry.Method("mean", "training mean (test only)", lambda seed, features, params, spm: MeanPose(),
                          "mean-model.npz", "mean pose", lambda: MeanPose)
    monkeypatch.setattr(registry, "METHODS", registry.METHODS + (row,))
    for table, value in ((registry.BY_NAME, row), (registry.METHOD_NAMES, row.title), (registry.SAVED_MODELS, row)):
        monkeypatch.setitem(table, row.name, value)
    return row


def test_a_method_added_as_one_row_with_a_model_file_is_fitted_saved_and_read_back(model_shards, tmp_path,
                                                                                   mean_row, monkeypatch):
    """Its splits run in the methods' fresh processes, which import the registry without the
    test's row (so they decline it there); the final model is fitted in this process (one worker)."""
    monkeypatch.setenv("SPM_PROGRESS_EVERY", "100000")   # no progress line among the lines read below
    runner = CliRunner()
    help_text = "".join(runner.invoke(model_cli, ["evaluate", "--help"]).output.split())   # wrapped at any hyphen
    assert "ormean-model.npz(meanpose),fromspmtrain" in help_text   # the help reads the rows
    shards, report = tmp_path / "s", tmp_path / "report"
    shutil.copytree(model_shards, shards)
    r = runner.invoke(model_cli, ["train", str(shards), "--out", str(report), "--runs", "1", "--protocol", "views",
                                  "--ellipse", "direct", "--methods", "pca,mean", "--workers", "1"])
    assert r.exit_code == 0, r.output
    assert r.output.splitlines()[-1].endswith(f"/results.md, models: {report}/mean-model.npz (mean pose)")
    payload = json.loads((report / "results.json").read_text())
    assert payload["context"]["models"] == {"mean": "written"}
    text = (report / "results.md").read_text()
    assert "Models trained on every training frame: `mean-model.npz` (mean pose)." in text
    poses = np.concatenate([read_shard(s, ["pose"])["pose"] for s in list_shards(shards)])
    _, arrays = load_model_file(report / "mean-model.npz", "mean")
    assert np.allclose(arrays["pose"], poses.mean(axis=0))   # views trains on every frame
    r = runner.invoke(model_cli, ["evaluate", str(shards), "--model", str(report / "mean-model.npz")])
    assert r.exit_code == 0 and r.output.splitlines()[-1].startswith("all"), r.output
    Image.fromarray(read_shard(list_shards(shards)[0], ["rgb"], frames=slice(0, 1))["rgb"][0]).save(tmp_path / "v.png")
    r = runner.invoke(model_cli, ["predict", "--model", str(report / "mean-model.npz"), str(tmp_path / "v.png"),
                                  "--json"])
    assert r.exit_code == 0, r.output
    assert np.allclose(list(json.loads(r.output)[0]["pose"].values()), poses.mean(axis=0))

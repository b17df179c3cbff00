import json
import shutil

import numpy as np
import pytest
from click.testing import CliRunner
from PIL import Image

from cli import model_cli
from spm_data.io.shards import read_shard
from spm_model.dataset import load_features
from spm_model.estimator import ModelError, SPMEstimator
from spm_model.evaluation import splits
from spm_model.features import FeatureConfig
from spm_model.metrics import pose_errors, summarise
from spm_model.train import evaluate_model, predict_images, train

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


def test_splits_never_share_a_view():
    from spm_model.dataset import FeatureTable

    n = 40
    t = FeatureTable({"class_name": np.array(["a"] * 20 + ["b"] * 20), "instance": np.array(["i"] * 20 + ["j"] * 20),
                      "path_index": np.tile(np.arange(10), 4)})            # each view twice (an occluded copy)
    (_, train, test), = splits(t, "views", seed=3)
    key = lambda i: (t.instance[i], t.path_index[i])  # noqa: E731
    assert len(train) + len(test) == n and not {key(i) for i in train} & {key(i) for i in test}
    loco = splits(t, "loco", seed=0)
    assert [c for c, _, _ in loco] == ["a", "b"] and set(t.class_name[loco[0][1]]) == {"b"}
    with pytest.raises(ModelError, match="at least 2 classes"):
        splits(t.subset(t.class_name == "a"), "loco", seed=0)


def test_train_loco_writes_the_report_and_model(model_shards, tmp_path):
    report = tmp_path / "report"
    result = train(model_shards, report, protocol="loco", runs=2, features=FAST)
    assert sorted(p.name for p in report.iterdir()) == ["accuracy.png", "model.npz", "occlusion.png",
                                                        "reference-model.npz", "results.json", "results.md"]
    payload = json.loads((report / "results.json").read_text())
    assert payload["schema"] == "spm-results" and payload["schema_version"] == 2
    assert payload["context"]["frames"] == 144 and len(payload["evaluation"]["runs"]) == 2
    summary = payload["summary"]
    assert set(summary["methods"]) == {"spm", "knn1", "knn3", "pca", "ls", "template"}
    assert set(summary["classes"]) == {"box", "car", "cup"}
    for entry in [*summary["methods"].values(), summary["chance"]]:
        assert 0 <= entry["success_tol5"] <= 100 and entry["success_sum3"] <= entry["success_sum5"] <= entry["success_tol5"]
        assert 0 <= entry["auc_45"] <= 100 and entry["geodesic_median_deg"] >= 0
        assert set(entry["median_error"]) >= {"azimuth_deg", "elevation_deg", "roll_deg", "distance_mm"}
        assert entry["surface"]["frames"] == 144 and "std" in entry
    assert summary["classes"]["cup"]["pca"]["frames"] == 48 and summary["classes"]["cup"]["pca"]["estimated"] == 48
    text = (report / "results.md").read_text()
    assert text.startswith("# Pose benchmark (loco protocol, 2 runs)\n\n- **Best method, loco protocol:")
    assert "Table 1 analogue" in text and "Table 2 analogue" in text and "| cup |" in text and "86.6" in text
    assert "ADD(-S)" in text and "chance (random training pose)" in text
    assert result["text"].splitlines()[0].startswith("- Best method, loco protocol:")
    # The final model predicts from an image.
    d = read_shard(sorted(model_shards.glob("cup*.h5"))[0], ["rgb", "pose"], frames=slice(0, 1))
    Image.fromarray(d["rgb"][0]).save(tmp_path / "cup.png")
    out = predict_images(report / "model.npz", [tmp_path / "cup.png"])
    assert set(out[0]["pose"]) == {"rx", "ry", "rz", "tx", "ty", "tz"} and out[0]["keypoints"] >= 16
    scored = evaluate_model(report / "model.npz", model_shards)
    assert scored["all"]["frames"] == 144 and set(scored["classes"]) == {"box", "car", "cup"}
    # The reference model too: it was trained on these very frames, so it finds each one.
    ref = evaluate_model(report / "reference-model.npz", model_shards)
    assert ref["all"]["success_tol5"] == 100.0 and ref["all"]["surface"]["add_s_recall"] == 100.0
    out = predict_images(report / "reference-model.npz", [tmp_path / "cup.png"], roi=(0, 0, 128, 128))
    assert np.allclose([out[0]["pose"][k] for k in ("rx", "ry", "rz")], d["pose"][0][:3], atol=5.01)


def test_cli_train_predict_evaluate_and_bad_input(model_shards, tmp_path):
    runner = CliRunner()
    shards = tmp_path / "s"
    shutil.copytree(model_shards, shards)
    r = runner.invoke(model_cli, ["train", "--shards", str(shards), "--runs", "1", "--ellipse", "direct",
                                  "--protocol", "views"])
    assert r.exit_code == 0, r.output
    assert "Best method, views protocol" in r.output and (shards / "report" / "model.npz").is_file()
    model = str(shards / "report" / "model.npz")
    d = read_shard(sorted(shards.glob("box*.h5"))[0], ["rgb"], frames=slice(3, 4))
    Image.fromarray(d["rgb"][0]).save(tmp_path / "box.png")
    Image.fromarray(np.zeros((48, 64, 3), np.uint8)).save(tmp_path / "black.png")
    r = runner.invoke(model_cli, ["predict", "--model", model, str(tmp_path / "box.png"), "--json"])
    assert r.exit_code == 0, r.output
    assert json.loads(r.output)[0]["image"].endswith("box.png")
    r = runner.invoke(model_cli, ["predict", "--model", model, str(tmp_path / "black.png")])
    assert r.exit_code == 1 and "SIFT found 0 keypoints" in r.output and "Traceback" not in r.output
    r = runner.invoke(model_cli, ["predict", "--model", model, str(tmp_path / "box.png"), "--roi", "500,500,4,4"])
    assert r.exit_code == 1 and "outside" in r.output
    r = runner.invoke(model_cli, ["evaluate", "--model", model, "--shards", str(shards)])
    assert r.exit_code == 0 and r.output.splitlines()[-1].startswith("all")
    (tmp_path / "empty").mkdir()
    for args, message in [(["train", "--shards", str(tmp_path / "empty")], "no shards"),
                          (["train", "--shards", str(tmp_path / "nope")], "no such folder"),
                          (["predict", "--model", str(tmp_path / "none.npz"), str(tmp_path / "box.png")],
                           "model file not found")]:
        r = runner.invoke(model_cli, args)
        assert r.exit_code == 1 and message in r.output and "Traceback" not in r.output, r.output


def test_a_class_with_too_few_frames_is_named(model_shards, tmp_path):
    shards = tmp_path / "s"
    shutil.copytree(model_shards, shards)
    from spm_data.io.shards import write_manifest, write_shard

    cup = sorted(shards.glob("cup*.h5"))[0]
    arrays = read_shard(cup, frames=slice(0, 4))
    cup.unlink()
    write_shard(cup, arrays, {"renderer": "pyrender", "seed": 1})
    write_manifest(shards)
    r = CliRunner().invoke(model_cli, ["train", "--shards", str(shards), "--ellipse", "direct", "--runs", "1"])
    assert r.exit_code == 1 and "class 'cup' has" in r.output and "need at least 10" in r.output, r.output

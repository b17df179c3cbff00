"""spm_model.commands.train: a loco run writes the report and both models, which predict from images and
evaluate shards; a class with too few frames is named."""

import json
import shutil

import numpy as np
import pytest
from click.testing import CliRunner
from PIL import Image

from cli import model_cli
from spm_data.io.shards import read_shard
from spm_model.commands.evaluate import evaluate_model
from spm_model.commands.predict import predict_images


@pytest.mark.slow  # the full benchmark (loco_report: every built-in method, 2 runs)
def test_train_loco_writes_the_report_and_model(model_shards, loco_report, tmp_path):
    result, report = loco_report  # train(model_shards, protocol="loco", runs=2) with a plug-in (tests/conftest.py)
    assert sorted(p.name for p in report.iterdir()) == ["accuracy.png", "model.npz", "occlusion.png",
                                                        "reference-model.npz", "results.json", "results.md"]
    payload = json.loads((report / "results.json").read_text())
    assert payload["schema"] == "spm-results" and payload["schema_version"] == 3
    assert payload["context"]["frames"] == 144 and len(payload["evaluation"]["runs"]) == 2
    summary = payload["summary"]
    assert set(summary["methods"]) == {"spm", "knn1", "knn3", "pca", "ls", "n3m", "smm", "template", "MeanPose"}
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


def test_a_class_with_too_few_frames_is_named(model_shards, tmp_path):
    shards = tmp_path / "s"
    shutil.copytree(model_shards, shards)
    from spm_data.io.shards import write_manifest, write_shard

    cup = sorted(shards.glob("cup*.h5"))[0]
    arrays = read_shard(cup, frames=slice(0, 4))
    cup.unlink()
    write_shard(cup, arrays, {"renderer": "pyrender", "seed": 1})
    write_manifest(shards)
    r = CliRunner().invoke(model_cli, ["train", str(shards), "--ellipse", "direct", "--runs", "1"])
    assert r.exit_code == 1 and "class 'cup' has" in r.output and "need at least 10" in r.output, r.output

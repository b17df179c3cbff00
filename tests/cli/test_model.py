"""spm_cli.model (spm): train, predict and evaluate end to end, and bad input as one-line errors."""

import json
import shutil

import numpy as np
from click.testing import CliRunner
from PIL import Image

from cli import model_cli
from spm_data.io.shards import read_shard


def test_cli_train_predict_evaluate_and_bad_input(model_shards, tmp_path):
    runner = CliRunner()
    shards = tmp_path / "s"
    shutil.copytree(model_shards, shards)
    r = runner.invoke(model_cli, ["train", str(shards), "--runs", "1", "--ellipse", "direct",
                                  "--protocol", "views", "--methods", "spm,template"])
    assert r.exit_code == 0, r.output
    assert "No method is called best here (views protocol)" in r.output and (shards / "report" / "model.npz").is_file()
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
    r = runner.invoke(model_cli, ["evaluate", str(shards), "--model", model])
    assert r.exit_code == 0 and r.output.splitlines()[-1].startswith("all")
    (tmp_path / "empty").mkdir()
    for args, message in [(["train", str(tmp_path / "empty")], "no shards"),
                          (["train", str(tmp_path / "nope")], "no such folder"),
                          (["predict", "--model", str(tmp_path / "none.npz"), str(tmp_path / "box.png")],
                           "model file not found")]:
        r = runner.invoke(model_cli, args)
        assert r.exit_code == 1 and message in r.output and "Traceback" not in r.output, r.output


def test_cli_offgrid_writes_the_fig5_tables_and_refuses_bad_method_names(model_shards, tmp_path):
    from spm_data.pipelines.occlude_jobs import occlude_dataset

    runner = CliRunner()
    shards = tmp_path / "train"
    shutil.copytree(model_shards, shards)
    occlude_dataset(shards, tmp_path / "test" / "occluded", low=0.0, high=0.95, copies=1, seed=3)
    report = tmp_path / "report"
    r = runner.invoke(model_cli, ["train", str(shards), "--test", str(tmp_path / "test"), "--out",
                                  str(report), "--runs", "1", "--ellipse", "direct", "--methods", "template,chance"])
    assert r.exit_code == 0, r.output
    assert "Fig. 5 (sum < 5° %, bins" in r.output
    payload = json.loads((report / "results.json").read_text())
    summary = payload["summary"]
    assert summary["protocol"] == "offgrid" and payload["context"]["test"] == str(tmp_path / "test")
    assert set(summary["methods"]) == {"template"} and set(summary["fig5"]) == {"all", "seen"}
    rows = summary["fig5"]["seen"]["rectangles"]["template"]
    assert sum(row["frames"] for row in rows) == 144 and payload["evaluation"]["train_occluded"] is False
    # The template matcher trained on these very views finds them while little is hidden.
    assert rows[0]["success_tol5"] == 100.0 and rows[0]["frames"] > 0
    text = (report / "results.md").read_text()
    assert "## Fig. 5, our reading of it" in text and "### seen instances, rectangles (spm-data occlude)" in text
    r = runner.invoke(model_cli, ["train", str(shards), "--methods", "template,nope"])
    assert r.exit_code == 1 and "--methods: unknown nope" in r.output and "Traceback" not in r.output
    r = runner.invoke(model_cli, ["train", str(shards), "--protocol", "views", "--test", str(shards)])
    assert r.exit_code == 1 and "--test goes with --protocol offgrid" in r.output


def test_train_fits_and_names_only_the_models_of_methods_asked_for(model_shards, tmp_path):
    shards = tmp_path / "s"
    shutil.copytree(model_shards, shards)
    (shards / "report").mkdir()
    (shards / "report" / "model.npz").write_bytes(b"an earlier run's model")   # must not be paired with this run
    r = CliRunner().invoke(model_cli, ["train", str(shards), "--runs", "1", "--protocol", "views",
                                       "--methods", "pca", "--methods", "chance"])   # repeated, as comma lists
    assert r.exit_code == 0, r.output
    assert r.output.splitlines()[-1].endswith("models: none (neither spm, template nor cnn was asked for)")
    assert sorted(p.name for p in (shards / "report").iterdir()) == ["accuracy.png", "occlusion.png", "results.json",
                                                                    "results.md"]
    payload = json.loads((shards / "report" / "results.json").read_text())
    assert payload["context"]["models"] == {}
    assert "No model was written." in (shards / "report" / "results.md").read_text()


def test_device_places_the_cnn_and_a_device_torch_cannot_use_is_one_line(model_shards, tmp_path, monkeypatch):
    import torch

    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)   # a CPU-only machine, GPU or not here
    runner = CliRunner()
    shards = tmp_path / "s"
    shutil.copytree(model_shards, shards)
    for device, message in [("cuda", "error: device 'cuda': torch sees no GPU here (a CPU-only build or no CUDA "
                                     "device); give --device cpu, or auto (which falls back to cpu)"),
                            ("gpu0", "error: device 'gpu0' is not one the cnn method takes; give auto, cpu, cuda or "
                                     "cuda:N")]:
        r = runner.invoke(model_cli, ["train", str(shards), "--methods", "cnn,chance", "--device", device])
        assert (r.exit_code, r.output.strip()) == (1, message)
        assert not (shards / "report").exists()                       # refused before any work
    r = runner.invoke(model_cli, ["train", str(shards), "--runs", "1", "--protocol", "views",
                                  "--methods", "cnn,template,chance", "--device", "cpu"])
    assert r.exit_code == 0, r.output
    assert "cnn device: cpu\n" in r.output                             # said before any work
    context = json.loads((shards / "report" / "results.json").read_text())["context"]
    assert context["model_params"] == {"cnn": {"device": "cpu"}} and context["training"]["cnn"]["device"] == "cpu"
    cnn, reference = str(shards / "report" / "cnn-model.npz"), str(shards / "report" / "reference-model.npz")
    d = read_shard(sorted(shards.glob("box*.h5"))[0], ["rgb"], frames=slice(3, 4))
    Image.fromarray(d["rgb"][0]).save(tmp_path / "box.png")
    r = runner.invoke(model_cli, ["predict", "--model", cnn, str(tmp_path / "box.png"), "--roi", "16,16,96,96",
                                  "--device", "cpu", "--json"])
    assert r.exit_code == 0 and len(json.loads(r.output)[0]["pose"]) == 6, r.output
    for args, message in [(["predict", "--model", cnn, str(tmp_path / "box.png"), "--device", "cuda:1"],
                           "error: device 'cuda:1': torch sees no GPU here"),
                          (["evaluate", str(shards), "--model", cnn, "--device", "cuda"],
                           "error: device 'cuda': torch sees no GPU here"),
                          (["predict", "--model", reference, str(tmp_path / "box.png"), "--device", "cpu"],
                           f"error: --device cpu: only a cnn model runs on a device, {reference} is a template "
                           "model; leave --device out")]:
        r = runner.invoke(model_cli, args)
        assert r.exit_code == 1 and r.output.startswith(message) and len(r.output.strip().splitlines()) == 1, r.output

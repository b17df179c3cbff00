"""spm_model.commands.cli_model (spm): train, predict and evaluate end to end, and bad input as one-line errors."""

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
    r = runner.invoke(model_cli, ["evaluate", str(shards), "--model", model])
    assert r.exit_code == 0 and r.output.splitlines()[-1].startswith("all")
    (tmp_path / "empty").mkdir()
    for args, message in [(["train", str(tmp_path / "empty")], "no shards"),
                          (["train", str(tmp_path / "nope")], "no such folder"),
                          (["predict", "--model", str(tmp_path / "none.npz"), str(tmp_path / "box.png")],
                           "model file not found")]:
        r = runner.invoke(model_cli, args)
        assert r.exit_code == 1 and message in r.output and "Traceback" not in r.output, r.output

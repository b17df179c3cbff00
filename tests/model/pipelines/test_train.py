"""spm_model.pipelines.train: a loco run writes the report and both models, which predict from images and
evaluate shards; every method gets its row on any data (a class with few frames, a small render, 32-pixel
turntable images, a transforms.json capture): figures, or declined with its reason."""

import json
import os
import shutil

import numpy as np
import pytest
from click.testing import CliRunner
from PIL import Image

from cli import model_cli
from spm_data.io.shards import read_shard
from spm_model.pipelines.check_estimator import CHECK_SPEC
from spm_model.pipelines.evaluate import evaluate_model
from spm_model.pipelines.predict import predict_images
from spm_model.methods.registry import METHOD_NAMES


@pytest.mark.slow  # the full benchmark (loco_report: every built-in method, 2 runs)
def test_train_loco_writes_the_report_and_model(model_shards, loco_report, tmp_path):
    result, report = loco_report  # train(model_shards, protocol="loco", runs=2) with a plug-in (tests/conftest.py)
    assert sorted(p.name for p in report.iterdir()) == ["accuracy.png", "cnn-model.npz", "cnn-model.safetensors",
                                                        "model.npz", "occlusion.png", "reference-model.npz",
                                                        "results.json", "results.md"]
    payload = json.loads((report / "results.json").read_text())
    assert payload["schema"] == "spm-results" and payload["schema_version"] == 5
    assert payload["context"]["frames"] == 144 and len(payload["evaluation"]["runs"]) == 2
    summary = payload["summary"]
    assert set(summary["methods"]) == {"spm", "knn1", "knn3", "pca", "ls", "n3m", "sift-pnp", "smm", "template",
                                       "cnn", "MeanPose"}
    assert set(summary["classes"]) == {"box", "car", "cup"}
    for entry in [*summary["methods"].values(), summary["chance"]]:
        assert 0 <= entry["success_tol5"] <= 100
        assert entry["success_sum3"] <= entry["success_sum5"] <= entry["success_tol5"]
        # No pose, no median: N3M's markers never pass on a class it did not train on (loco).
        assert 0 <= entry["auc_45"] <= 100 and (entry["geodesic_median_deg"] is None) == (entry["estimated"] == 0)
        assert entry["estimated"] == 0 or entry["geodesic_median_deg"] >= 0
        assert set(entry["median_error"]) >= {"azimuth_deg", "elevation_deg", "roll_deg", "distance_mm"}
        assert entry["surface"]["frames"] == 144 and "std" in entry
    assert summary["classes"]["cup"]["pca"]["frames"] == 48 and summary["classes"]["cup"]["pca"]["estimated"] == 48
    text = (report / "results.md").read_text()
    best = summary["best"]  # named only where it beats chance beyond both 95% intervals
    first = f"- **Best method, loco protocol: {METHOD_NAMES[best]}**" if best else "- **No method beats chance here"
    assert text.startswith("# Pose benchmark (loco protocol, 2 runs)\n\n" + first)
    if best:
        ci = summary["methods"][best]["ci95"]["success_tol5"]
        assert ci["low"] > summary["chance"]["ci95"]["success_tol5"]["high"] and ci["n"] == 144
    assert "Table 1 analogue" in text and "Table 2 analogue" in text and "| cup |" in text and "86.6" in text
    assert "ADD(-S)" in text and "chance (random training pose)" in text
    assert result["text"].splitlines()[0].startswith(first.replace("**", ""))
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


def test_a_class_with_too_few_frames_no_longer_stops_the_other_methods(model_shards, tmp_path):
    """SPM's feature gate is SPM's alone: a class of 4 frames trains nothing for SPM when it is the
    only training class, and every method still gets its row (figures, or declined with why)."""
    shards = tmp_path / "s"
    shutil.copytree(model_shards, shards)
    from spm_data.io.shards import write_manifest, write_shard

    cup = sorted(shards.glob("cup*.h5"))[0]
    arrays = read_shard(cup, frames=slice(0, 4))
    cup.unlink()
    write_shard(cup, arrays, {"renderer": "pyrender", "seed": 1})
    write_manifest(shards)
    r = CliRunner().invoke(model_cli, ["train", str(shards), "--ellipse", "direct", "--runs", "1",
                                       "--methods", "spm,pca,chance"])
    assert r.exit_code == 0, r.output
    summary = json.loads((shards / "report" / "results.json").read_text())["summary"]
    assert summary["classes"]["cup"]["pca"]["frames"] == 4 and summary["methods"]["spm"]["frames"] == 100


# --------------------------------------------------------------------------- every method out, on any data

# check-estimator's set with one instance a class: 24 views (azimuth 0-55, elevations 10 and 15) at 64 px.
TWO_CLASS_SPEC = CHECK_SPEC.replace("instances = 2", "instances = 1")


def _rows(report) -> dict:
    """{built-in method: "figures" or its decline reason} from a report's results.json."""
    from spm_model.methods.registry import METHOD_NAMES

    summary = json.loads((report / "results.json").read_text())["summary"]
    scored = {**summary["methods"], **({"chance": summary["chance"]} if summary["chance"] else {})}
    return {m: "figures" if m in scored else summary["declined"][m]["reason"] for m in METHOD_NAMES}


def test_default_methods_on_a_two_class_24_frame_render_each_have_a_row(tmp_path):
    """The issue's small render: SMM cannot pair sequences (one camera path per training class
    under loco) and is declined with why; every other method is scored; exit 0."""
    from spm_data.pipelines.render_jobs import load_run_specs, render_dataset

    (tmp_path / "specs").mkdir()
    for cls in ("cup", "box"):
        (tmp_path / "specs" / f"{cls}.toml").write_text(TWO_CLASS_SPEC.format(cls=cls))
    render_dataset(load_run_specs(all_classes=True, specs_dir=tmp_path / "specs"), tmp_path / "out")
    r = CliRunner().invoke(model_cli, ["train", str(tmp_path / "out"), "--runs", "1", "--ellipse", "direct"])
    assert r.exit_code == 0, r.output
    rows = _rows(tmp_path / "out" / "report")
    assert rows["smm"].startswith("needs 2 camera paths (sequences) among the training frames, got 1"), rows
    assert all(v == "figures" for m, v in rows.items() if m != "smm"), rows
    assert "- SMM (Mei et al. 2011) declined: needs 2 camera paths" in r.output


def test_default_methods_on_a_32_px_coil_layout_set_each_have_a_row(tmp_path):
    """Grey 32-pixel turntable images (COIL-20's layout, as its public copies circulate): N3M has
    no depth to lift points with and says so; the rest run, each with its coverage."""
    import cv2

    from spm_data.formats.coil100 import import_coil20
    from tests.helpers import coil_image

    root = tmp_path / "coil20"
    root.mkdir()
    for obj in (1, 2, 3):
        for view in range(24):
            img = cv2.resize(coil_image(obj * 3, 15 * view), (32, 32), interpolation=cv2.INTER_AREA)
            cv2.putText(img, str(obj), (8 + view % 8, 20), cv2.FONT_HERSHEY_PLAIN, 0.8, (255, 255, 255))
            cv2.imwrite(str(root / f"obj{obj}__{view}.png"), img.max(axis=2))
    import_coil20(root, tmp_path / "imported")
    r = CliRunner().invoke(model_cli, ["train", str(tmp_path / "imported"), "--runs", "1", "--ellipse", "direct"])
    assert r.exit_code == 0, r.output
    rows = _rows(tmp_path / "imported" / "report")
    for method in ("n3m", "sift-pnp"):
        assert rows[method].startswith("needs depth: none of the 48 training frames has a measured depth"), rows
    assert {m for m, v in rows.items() if v == "figures"} >= {"pca", "ls", "template", "chance"}
    summary = json.loads((tmp_path / "imported" / "report" / "results.json").read_text())["summary"]
    for m, entry in summary["methods"].items():
        assert entry["coverage"] == 100.0 * entry["estimated"] / entry["frames"], m


def test_a_transforms_json_capture_trains_under_views_with_every_method(tmp_path):
    """One captured object: leave-one-class-out cannot run, so the views protocol does (said in one
    line), and every method has a row."""
    from spm_data.pipelines.render_jobs import load_run_specs, render_dataset
    from spm_data.formats.nerf import import_nerf
    from spm_data.io.shards import list_shards
    from tests.helpers import CENTER, SCALE, write_capture

    (tmp_path / "specs").mkdir()
    (tmp_path / "specs" / "cup.toml").write_text(TWO_CLASS_SPEC.format(cls="cup"))
    render_dataset(load_run_specs(all_classes=True, specs_dir=tmp_path / "specs"), tmp_path / "render")
    d = read_shard(list_shards(tmp_path / "render")[0])
    write_capture(tmp_path / "scan", d["rgb"], d["mask"] > 0, d["K"], d["R"], d["t"], depth=d["depth"])
    import_nerf(tmp_path / "scan", tmp_path / "imported", scale=SCALE, center=CENTER)
    r = CliRunner().invoke(model_cli, ["train", str(tmp_path / "imported"), "--runs", "1", "--ellipse", "direct"])
    assert r.exit_code == 0, r.output
    assert "one class (scan): leave-one-class-out cannot run, so the views protocol does (new views of seen " \
           "objects); frames on a camera path (a capture, a turntable) test more views with --protocol interleaved" \
           in r.output
    rows = _rows(tmp_path / "imported" / "report")
    assert json.loads((tmp_path / "imported" / "report" / "results.json").read_text())["summary"]["protocol"] == "views"
    assert set(rows) == {"spm", "knn1", "knn3", "pca", "ls", "n3m", "sift-pnp", "smm", "template", "cnn", "chance"}
    assert rows["smm"].startswith("needs 2 camera paths"), rows


def test_loco_on_one_class_is_refused_before_any_feature_is_extracted(tmp_path, small_specs_dir):
    from spm_data.pipelines.render_jobs import load_run_specs, render_dataset

    render_dataset(load_run_specs(classes=["cup"], specs_dir=small_specs_dir), tmp_path / "out", limit=4)
    r = CliRunner().invoke(model_cli, ["train", str(tmp_path / "out"), "--protocol", "loco"])
    assert r.exit_code == 1 and r.output.startswith("error: leave-one-class-out needs at least 2 classes, found "
                                                    "['cup']"), r.output
    assert not (tmp_path / "out" / ".spm-features").exists()


def test_when_no_method_but_chance_can_run_train_exits_1_with_one_line(tmp_path):
    """Only methods that need what the data lacks: one line naming each and why, no report."""
    import cv2

    from spm_data.formats.coil100 import import_coil20
    from tests.helpers import coil_image

    root = tmp_path / "coil20"
    root.mkdir()
    for obj in (1, 2):
        for view in range(12):
            cv2.imwrite(str(root / f"obj{obj}__{view}.png"), coil_image(obj, 5 * view))
    import_coil20(root, tmp_path / "imported")
    r = CliRunner().invoke(model_cli, ["train", str(tmp_path / "imported"), "--methods", "n3m,chance"])
    assert r.exit_code == 1, r.output
    errors = [line for line in r.output.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and errors[0].startswith("error: no method could run on this data (chance aside): n3m: "
                                                     "needs depth"), r.output
    assert not (tmp_path / "imported" / "report").exists()


def test_a_plug_in_with_a_wrong_needs_is_refused_before_any_work(tmp_path, monkeypatch):
    from spm_model.errors import ModelError
    from spm_model.pipelines.train import load_estimators

    (tmp_path / "odd_pose.py").write_text("class Odd:\n    NEEDS = {'depth': True}\n"
                                          "    def fit(self, f, p):\n        return self\n"
                                          "    def predict(self, f):\n        return None\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    with pytest.raises(ModelError, match=r"^--estimator odd_pose:Odd: Odd.NEEDS must be a "
                                         r"spm_model.base.estimator.Needs"):
        load_estimators(["odd_pose:Odd"])


def test_a_second_train_into_a_locked_report_folder_is_refused_with_the_first_ones_pid(model_shards, tmp_path):
    """Two spm train into one --out both exited 0 and the report was whichever ended last (4 of 4
    pairs). Now the report folder is locked for the whole run, as a shard folder is."""
    import os

    from spm_data.io.locking import OutputLock

    report = tmp_path / "report"
    report.mkdir()
    with OutputLock(report):   # a run of this host that is still going
        r = CliRunner().invoke(model_cli, ["train", str(model_shards), "--out", str(report), "--runs", "1",
                                           "--methods", "pca,chance", "--protocol", "views"])
    assert r.exit_code == 1, r.output
    line = r.output.strip().splitlines()[-1]
    assert line.startswith(f"error: another run is writing to {report}/ (pid {os.getpid()} on ") and \
        line.endswith("wait for it to finish or stop it")
    assert sorted(p.name for p in report.iterdir()) == []          # nothing of the refused run, lock released
    r = CliRunner().invoke(model_cli, ["train", str(model_shards), "--out", str(tmp_path / "new" / "r"), "--runs",
                                       "1", "--methods", "spm,chance", "--protocol", "loco"])
    assert r.exit_code == 0 and not list((tmp_path / "new" / "r").glob(".spm.lock*")), r.output


class Steps:
    """A progress callable recording each step (phase) and the counts fed to it."""

    def __init__(self):
        self.steps = []

    def phase(self, label, total=None, unit="frame"):
        self.steps.append([label, total, unit, 0])

    def __call__(self, n=1):
        self.steps[-1][3] += n


def test_train_reports_each_step_features_first(tmp_path):
    """spm train's long steps each say how far they are: every frame's features (24 frames a
    class, none cached yet), the splits and final models fitted, the runs scored, the report."""
    from spm_data.pipelines.render_jobs import load_run_specs, render_dataset
    from spm_model.pipelines.train import train
    from spm_model.spm.features import FeatureConfig

    (tmp_path / "specs").mkdir()
    for cls in ("cup", "box"):
        (tmp_path / "specs" / f"{cls}.toml").write_text(TWO_CLASS_SPEC.format(cls=cls))
    render_dataset(load_run_specs(all_classes=True, specs_dir=tmp_path / "specs"), tmp_path / "out")
    progress = Steps()
    train(tmp_path / "out", runs=1, features=FeatureConfig(ellipse="direct"), builtins=["knn1", "template"],
          progress=progress)
    assert progress.steps == [["checking cached features", 2, "shard", 2], ["features", 48, "frame", 48],
                              # loco: 2 (the final models uncounted)
                              ["reading features", 2, "shard", 2], ["fitting", 2, "split", 2],
                              ["scoring", 1, "run", 1], ["report", None, None, 0]]
    progress = Steps()   # again: every feature cached
    train(tmp_path / "out", runs=1, features=FeatureConfig(ellipse="direct"), builtins=["knn1"], progress=progress)
    assert progress.steps[:3] == [["checking cached features", 2, "shard", 2], ["features", 0, "frame", 0],
                                  ["reading features", 2, "shard", 2]]


def test_the_length_unit_of_a_capture_imported_without_scale(tmp_path):
    from spm_data.core.poses import camera_pose, intrinsics_from_fov
    from spm_data.formats.nerf import import_nerf
    from spm_model.pipelines.train import length_unit
    from tests.helpers import write_capture

    rgb = np.zeros((2, 20, 30, 3), np.uint8)
    rgb[:, 5:15, 10:20] = 200
    poses = [camera_pose(10.0 * i, 10.0, 0.0, 0.6) for i in range(2)]
    capture = write_capture(tmp_path / "c", rgb, rgb.max(axis=3) > 0, np.stack([intrinsics_from_fov(40, 30, 20)] * 2),
                            np.stack([p[0] for p in poses]), np.stack([p[1] for p in poses]))
    import_nerf(capture, tmp_path / "metric", scale=0.5)
    assert length_unit(tmp_path / "metric") == "m"
    with pytest.warns(Warning, match="no --scale"):
        import_nerf(capture, tmp_path / "units")
    assert length_unit(tmp_path / "units") == length_unit(tmp_path / "metric", tmp_path / "units") == "capture unit"



def test_frames_without_path_neighbours_are_expected_under_render_limit_and_said_so(tmp_path, small_specs_dir):
    from types import SimpleNamespace

    from spm_data.pipelines.occlude_jobs import occlude_dataset
    from spm_data.pipelines.render_jobs import load_run_specs, render_dataset
    from spm_data.io.shards import list_shards
    from spm_model.pipelines.train import alone_line

    render_dataset(load_run_specs(classes=["cup"], specs_dir=small_specs_dir), tmp_path / "limited", limit=4)
    render_dataset(load_run_specs(classes=["box"], specs_dir=small_specs_dir), tmp_path / "full")
    occlude_dataset(tmp_path / "limited", tmp_path / "occluded")   # as make demo: the copies keep --limit
    limited, full = list_shards(tmp_path / "limited")[0], list_shards(tmp_path / "full")[0]
    occluded = list_shards(tmp_path / "occluded")[0]
    table = SimpleNamespace(train_neighbours=np.array([0, 0, 1]), shard=np.array([str(limited), str(occluded),
                                                                                  str(full)]))
    assert alone_line(table) == ("2 frames have no 5-degree path neighbour in their shard, as expected: "
                                 "`spm-data render --limit` spreads a shard's frames over its camera path; their "
                                 "training features use every keypoint in the mask (docs/method.md)")
    table.train_neighbours = np.array([0, 1, 0])   # one of them in a shard rendered without --limit
    assert alone_line(table).startswith("2 frames have no 5-degree path neighbour in their shard; their training")



def test_the_data_lines_class_counts_add_up_to_its_frames_with_or_without_features():
    """make demo's line once counted only frames with SPM's features per class (1,524 of 1,728)."""
    from spm_model.pipelines.train import class_counts, data_line

    class Table:
        class_name = np.array(["cup"] * 4 + ["box"] * 3)
        train_vector = np.ones((7, 16))

        def __len__(self):
            return 7

    table = Table()
    table.train_vector[[0, 1, 5]] = np.nan   # three frames without SPM's training features
    assert data_line(table, class_counts(table)) == "7 frames, 2 classes: box 3, cup 4; 4 with SPM's training features"


BAD_PLUGINS = '''
import os

import numpy as np


class Fine:
    def fit(self, frames, poses):
        self.mean_ = np.asarray(poses).mean(axis=0)
        return self

    def predict(self, frames):
        return np.tile(self.mean_, (len(frames), 1))


class EndsRun(Fine):
    def fit(self, frames, poses):
        raise SystemExit(0)


class ExitsInPredict(Fine):
    def predict(self, frames):
        os._exit(0)


class Interrupts(Fine):
    def fit(self, frames, poses):
        raise KeyboardInterrupt


class Sleeps(Fine):
    def fit(self, frames, poses):
        import threading

        threading.Event().wait()   # blocks until its process is ended (never a fixed time)
'''


@pytest.mark.parametrize("workers", ["1", "2"])
def test_plug_in_code_cannot_end_the_run_each_way_is_a_declined_method(model_shards, tmp_path, monkeypatch, workers):
    """SystemExit(0) in fit ended spm train with exit 0 and no report; os._exit(0) in predict with
    --workers 1 did too, leaving .spm.lock; a plug-in's own KeyboardInterrupt read as the user's
    Ctrl-C; a sleeping fit ran for ever. Each is now a declined method with why."""
    (tmp_path / "bad_pose.py").write_text(BAD_PLUGINS)
    monkeypatch.syspath_prepend(str(tmp_path))
    report = tmp_path / "report"
    args = ["train", str(model_shards), "--out", str(report), "--runs", "1", "--protocol", "views", "--methods",
            "chance", "--timeout", "5", "--workers", workers]
    for name in ("Fine", "EndsRun", "ExitsInPredict", "Interrupts", "Sleeps"):
        args += ["--estimator", f"bad_pose:{name}"]
    r = CliRunner().invoke(model_cli, args)
    assert r.exit_code == 0, r.output
    summary = json.loads((report / "results.json").read_text())["summary"]
    assert {name: d["reason"] for name, d in summary["declined"].items()} == {
        "EndsRun": "it raised SystemExit (exit code 0); a method cannot end the run",
        "ExitsInPredict": "predict: the method's process ended (exit code 0) without a result",
        "Interrupts": "it raised KeyboardInterrupt itself (not the user's Ctrl-C)",
        "Sleeps": "fit: took longer than the time limit (--timeout 5 s)"}
    assert summary["methods"]["Fine"]["estimated"] == summary["methods"]["Fine"]["frames"] > 0
    assert not list(report.glob(".spm.lock*")) and "interrupted" not in r.output


def test_a_plug_in_module_that_exits_as_it_is_imported_is_refused_in_one_line(tmp_path, monkeypatch):
    (tmp_path / "quits_pose.py").write_text("raise SystemExit(0)\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    r = CliRunner().invoke(model_cli, ["train", str(tmp_path), "--estimator", "quits_pose:Any"])
    assert (r.exit_code, r.output) == (1, "error: --estimator quits_pose:Any: cannot import quits_pose (SystemExit: "
                                          "0); is its folder on PYTHONPATH?\n")


@pytest.mark.parametrize("workers", ["1", "2"])
def test_a_plug_in_module_is_imported_only_in_its_own_processes(model_shards, tmp_path, monkeypatch, notes, workers):
    """Its module-level code (an import-time hook) never runs where labels are: not in the command's
    process, nor in a worker; only in a process of its own (started as `python -c`)."""
    (tmp_path / "where_pose.py").write_text("import os, sys\nfrom tests.helpers import note\n"
                                            "note([os.getpid(), sys.argv[0]])\n" + BAD_PLUGINS)
    monkeypatch.syspath_prepend(str(tmp_path))
    r = CliRunner().invoke(model_cli, ["train", str(model_shards), "--out", str(tmp_path / "r"), "--runs", "1",
                                       "--protocol", "views", "--methods", "chance", "--workers", workers,
                                       "--estimator", "where_pose:Fine"])
    assert r.exit_code == 0, r.output
    imports = notes()
    assert len(imports) >= 2 and all(argv == "-c" for _, argv in imports), imports   # described, then a split
    assert os.getpid() not in {pid for pid, _ in imports}

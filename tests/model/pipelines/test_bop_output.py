"""spm_model.pipelines.bop_output: --bop-results of spm train and spm evaluate, end to end on a tiny
render: the files bop_toolkit reads, numbered as spm-data export bop numbers the frames."""

import json

import numpy as np
import pytest
from click.testing import CliRunner

from cli import data_cli, model_cli
from spm_data.formats.bop.ids import frame_ids
from spm_data.formats.bop.results import HEADER, load_bop_results, load_test_targets


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    """cup and box, 12 frames each (64 px, shards of 8 frames), exported as BOP split "test"."""
    from spm_data.pipelines.render_jobs import load_run_specs, render_dataset
    from tests.helpers import write_small_specs

    root = tmp_path_factory.mktemp("bop")
    render_dataset(load_run_specs(all_classes=True, specs_dir=write_small_specs(root / "specs")), root / "render",
                   limit=12)
    r = CliRunner().invoke(data_cli, ["export", "bop", str(root / "render"), "--out", str(root / "export"),
                                      "--split", "test"])
    assert r.exit_code == 0, r.output
    return root


def _gt(export):
    """{(scene_id, im_id): scene_gt's first entry} of the export's split "test"."""
    out = {}
    for scene in sorted((export / "test").iterdir()):
        for im, entries in json.loads((scene / "scene_gt.json").read_text()).items():
            out[(int(scene.name), int(im))] = entries[0]
    return out


def test_the_export_lists_every_frame_as_a_target(tiny):
    targets = load_test_targets(tiny / "export" / "test_targets_bop19.json")
    gt = _gt(tiny / "export")
    assert len(targets) == len(gt) == 24
    assert {(t["scene_id"], t["im_id"]): t["obj_id"] for t in targets} == {k: v["obj_id"] for k, v in gt.items()}
    assert all(t["inst_count"] == 1 for t in targets)


def test_train_writes_each_methods_first_run_estimates_and_no_row_without_one(tiny, tmp_path):
    out = tmp_path / "results"
    r = CliRunner().invoke(model_cli, ["train", str(tiny / "render"), "--methods", "template,n3m", "--runs", "1",
                                       "--out", str(tmp_path / "report"), "--bop-results", str(out)])
    assert r.exit_code == 0, r.output
    assert sorted(p.name for p in out.iterdir()) == ["n3m_spm-test.csv", "template_spm-test.csv"]
    assert f"bop results: {out / 'n3m_spm-test.csv'}, {out / 'template_spm-test.csv'}" in r.output
    # loco: every frame is tested once; the template method estimates each, N3M none (unseen classes).
    rows = load_bop_results(out / "template_spm-test.csv")
    targets = load_test_targets(tiny / "export" / "test_targets_bop19.json")
    assert sorted((x["scene_id"], x["im_id"], x["obj_id"]) for x in rows) == \
        sorted((t["scene_id"], t["im_id"], t["obj_id"]) for t in targets)
    assert (out / "n3m_spm-test.csv").read_text() == HEADER
    assert all(x["t"][2] > 100 for x in rows)   # millimetres (the camera is 0.6 or 0.7 m away)
    # The rows are run 1's estimates: as many as the report counts for run 1.
    run1 = json.loads((tmp_path / "report" / "results.json").read_text())["evaluation"]["runs"][0]["overall"]
    assert run1["template"]["estimated"] == len(rows) and run1["n3m"]["estimated"] == 0


def test_evaluate_writes_a_row_per_frame_with_the_exports_ids(tiny, tmp_path):
    runner = CliRunner()
    r = runner.invoke(model_cli, ["train", str(tiny / "render"), "--methods", "template", "--runs", "1",
                                  "--protocol", "views", "--out", str(tmp_path / "report")])
    assert r.exit_code == 0, r.output
    out = tmp_path / "eval"
    r = runner.invoke(model_cli, ["evaluate", str(tiny / "render"), "--model", str(tmp_path / "report" /
                                  "reference-model.npz"), "--bop-results", str(out), "--bop-dataset", "tiny",
                                  "--bop-split", "val"])
    assert r.exit_code == 0, r.output
    assert f"bop results: {out / 'template_tiny-val.csv'}" in r.output
    rows = load_bop_results(out / "template_tiny-val.csv")
    gt = _gt(tiny / "export")
    assert len(rows) == len(gt) == 24
    assert all(row["obj_id"] == gt[(row["scene_id"], row["im_id"])]["obj_id"] for row in rows)
    # The reference model, trained on these very frames, finds each one's view (its distance may
    # be the other of 0.6 and 0.7 m: the template is matched at any scale).
    same = [np.allclose(row["R"].ravel(), gt[(row["scene_id"], row["im_id"])]["cam_R_m2c"], atol=1e-6)
            for row in rows]
    assert sum(same) >= 20, same


def test_each_frames_ground_truth_label_becomes_its_exports_scene_gt(tiny, tmp_path):
    """The mapping alone: the table's own labels written as estimates are the export's ground
    truth, row for row (same scene, image, object, R, and t in mm)."""
    from spm_model.bench.feature_cache import load_features
    from spm_model.pipelines.bop_output import BopOutput
    from spm_model.spm.features import FeatureConfig

    table = load_features(tiny / "render", FeatureConfig(ellipse="direct"))
    order = np.random.default_rng(0).permutation(len(table))   # any row order
    written = BopOutput(tmp_path / "r").write(tiny / "render", table, {"gt": (order, table.pose[order])})
    rows = load_bop_results(written[0])
    gt = _gt(tiny / "export")
    assert len(rows) == len(gt) == 24
    for row in rows:
        entry = gt[(row["scene_id"], row["im_id"])]
        assert row["obj_id"] == entry["obj_id"]
        np.testing.assert_allclose(row["R"].ravel(), entry["cam_R_m2c"], atol=1e-9)
        np.testing.assert_allclose(row["t"], entry["cam_t_m2c"], atol=1e-6)
    ids = frame_ids(tiny / "render")
    assert sorted(zip(ids.scene_id.tolist(), ids.im_id.tolist())) == sorted(gt)


@pytest.mark.parametrize("args, message", [
    (["--bop-dataset", "my-set"], "error: --bop-dataset 'my-set': expected letters and digits only"),
    (["--bop-split", "test_pbr"], "error: --bop-split 'test_pbr': expected letters and digits only"),
    (["--bop-ids-from", "/no/such/export"], "error: --bop-ids-from /no/such/export: no such export")])
def test_bad_names_are_refused_in_one_line_before_any_work(tiny, tmp_path, args, message):
    for command in (["train", str(tiny / "render"), "--out", str(tmp_path / "report")],
                    ["evaluate", str(tiny / "render"), "--model", str(tmp_path / "none.npz")]):
        r = CliRunner().invoke(model_cli, command + ["--bop-results", str(tmp_path / "r"), *args])
        assert r.exit_code == 1 and r.output.startswith(message), r.output
        assert len(r.output.strip().splitlines()) == 1
    assert not (tmp_path / "r").exists() and not (tmp_path / "report").exists()


def test_frames_of_another_folder_are_refused_in_one_line(tiny, tmp_path):
    from spm_data.errors import SpmError
    from spm_model.bench.feature_cache import FeatureTable
    from spm_model.pipelines.bop_output import BopOutput, frame_positions

    shard = sorted((tiny / "render").glob("*.h5"))[1]
    table = FeatureTable({"pose": np.zeros((3, 6)), "shard": np.array([str(shard)] * 2 + ["/elsewhere/x.h5"]),
                          "frame": np.array([0, 1, 0])})
    where = frame_positions(tiny / "render", table)
    assert where[2] == -1 and where[1] == where[0] + 1 >= 1
    with pytest.raises(SpmError, match="1 frames are not in") as err:
        BopOutput(tmp_path / "r").write(tiny / "render", table, {"m": (np.arange(3), np.zeros((3, 6)))})
    assert "\n" not in str(err.value)


def test_shards_in_subfolders_are_refused_in_one_line_before_any_work(tiny, tmp_path):
    import shutil

    shutil.copytree(tiny / "render", tmp_path / "nest" / "inner")
    for command in (["train", str(tmp_path / "nest"), "--out", str(tmp_path / "report")],
                    ["evaluate", str(tmp_path / "nest"), "--model", str(tmp_path / "none.npz")]):
        r = CliRunner().invoke(model_cli, command + ["--bop-results", str(tmp_path / "r")])
        assert r.exit_code == 1 and len(r.output.strip().splitlines()) == 1, r.output
        assert "holds its shards in subfolders (inner/…)" in r.output
    assert not (tmp_path / "r").exists() and not (tmp_path / "report").exists()


def test_a_bop_results_folder_that_cannot_be_written_is_refused_before_any_work(tiny, tmp_path):
    """Issue 47: refused only after the features and the fits (and the report then not written)."""
    (tmp_path / "file").write_text("in the way")
    for where, said in ((tmp_path / "file" / "r", f"cannot write there: {tmp_path / 'file'} is a file"),
                        (tmp_path / ("x" * 300), "is 300 bytes, over the")):
        for command in (["train", str(tiny / "render"), "--out", str(tmp_path / "report")],
                        ["evaluate", str(tiny / "render"), "--model", str(tmp_path / "none.npz")]):
            r = CliRunner().invoke(model_cli, command + ["--bop-results", str(where)])
            assert r.exit_code == 1 and len(r.output.strip().splitlines()) == 1, r.output
            assert r.output.startswith("error: --bop-results") and said in r.output, r.output
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file"]   # no report, no features, nothing

"""spm_data.formats.bop.results: BOP results files (bop_toolkit's bop19 CSV) and test targets."""

import json

import numpy as np
import pytest

from spm_data.core.poses import label_to_pose
from spm_data.errors import SpmError
from spm_data.formats.bop.ids import FrameIds
from spm_data.formats.bop.results import (HEADER, load_bop_results, load_test_targets, method_name, pose_rows,
                                          result_file_name, save_bop_results, save_test_targets, test_targets,
                                          write_test_targets)

IDS = FrameIds(obj_id=np.array([1, 1, 2]), scene_id=np.array([0, 0, 1]), im_id=np.array([0, 1, 0]))
LABELS = np.array([[10.0, 20.0, 30.0, 0.01, -0.02, 0.5],
                   [np.nan] * 6,
                   [-170.0, 5.0, 90.0, 0.0, 0.1, 0.75]])


def test_rows_round_trip_in_millimetres_and_a_frame_without_estimate_has_no_row(tmp_path):
    rows = pose_rows(IDS, LABELS)
    assert [(r["scene_id"], r["im_id"], r["obj_id"]) for r in rows] == [(0, 0, 1), (1, 0, 2)]
    path = save_bop_results(tmp_path / "m_spm-test.csv", rows)
    text = path.read_text()
    assert text.splitlines()[0] == HEADER and len(text.splitlines()) == 3
    assert not list(tmp_path.glob(".*partial"))   # written to a temporary name, renamed
    back = load_bop_results(path)
    R, t = label_to_pose(LABELS[[0, 2]])
    for row, r, tt in zip(back, R, t):
        assert row["score"] == 1.0 and row["time"] == -1.0
        np.testing.assert_array_equal(row["R"], r)   # repr: every digit kept
        np.testing.assert_array_equal(row["t"], 1000.0 * tt)
    assert back[0]["t"][2] == 500.0 and back[1]["t"][2] == 750.0
    # bop_toolkit's layout: R 9 numbers row-major, space-separated; t 3 numbers.
    fields = text.splitlines()[1].split(",")
    assert len(fields) == 7 and len(fields[4].split()) == 9 and len(fields[5].split()) == 3
    assert [float(v) for v in fields[4].split()] == R[0].ravel().tolist()


def test_frame_positions_scores_and_times_are_used():
    rows = pose_rows(IDS, LABELS[[2]], frames=[2], scores=[0.5], times=[0.25])
    assert len(rows) == 1 and (rows[0]["scene_id"], rows[0]["obj_id"]) == (1, 2)
    assert rows[0]["score"] == 0.5 and rows[0]["time"] == 0.25


def test_frame_positions_out_of_the_folder_are_refused_in_one_line():
    with pytest.raises(SpmError, match="expected frame positions 0..2, got 0..5") as err:
        pose_rows(IDS, LABELS[:2], frames=[0, 5])
    assert "\n" not in str(err.value)
    with pytest.raises(SpmError, match="one frame per estimate"):
        pose_rows(IDS, LABELS, frames=[0])


def test_the_name_rule_and_bad_names_refused_in_one_line():
    assert result_file_name("sift-pnp") == "sift-pnp_spm-test.csv"
    assert result_file_name("my_pose:Mean Pose", "lm", "val") == "my-pose-Mean-Pose_lm-val.csv"
    assert method_name("__x__") == "x"
    for dataset, split in (("s-pm", "test"), ("my_set", "test"), ("spm", "test_pbr"), ("spm", ""), ("a.b", "t")):
        with pytest.raises(SpmError, match="expected letters and digits only") as err:
            result_file_name("m", dataset, split)
        assert "\n" not in str(err.value)
    with pytest.raises(SpmError, match="got none"):
        method_name("__")


@pytest.mark.parametrize("content, where", [("1,2,3\n", "line 1"), (HEADER + "\n0,0,1,1,1 2 3,0 0 0,-1\n", "line 2"),
                                            (HEADER + "\n0,x,1,1,1 0 0 0 1 0 0 0 1,0 0 0,-1", "line 2")])
def test_a_malformed_results_file_is_refused_in_one_line_naming_the_line(tmp_path, content, where):
    path = tmp_path / "bad.csv"
    path.write_text(content)
    with pytest.raises(SpmError, match=where) as err:
        load_bop_results(path)
    assert "\n" not in str(err.value) and str(path) in str(err.value)
    with pytest.raises(SpmError, match="cannot read it"):
        load_bop_results(tmp_path / "missing.csv")


def _export(root):
    """A tiny export: objects 1, 2 (targets) and 3 (a distractor), two scenes."""
    (root / "test" / "000000").mkdir(parents=True)
    (root / "test" / "000001").mkdir()
    (root / "objects.json").write_text(json.dumps({
        "1": {"class": "cup", "instance": "a", "instance_id": 0},
        "2": {"class": "cup", "instance": "b", "instance_id": 1},
        "3": {"class": "distractor", "instance": "d", "instance_id": 0, "role": "distractor"},
        "4": {"class": "coil", "instance": "c", "instance_id": 0, "ground_truth": "image-only"}}))
    gt = lambda *ids: [{"obj_id": i, "cam_R_m2c": [1, 0, 0, 0, 1, 0, 0, 0, 1], "cam_t_m2c": [0, 0, 1]} for i in ids]  # noqa: E731
    (root / "test" / "000000" / "scene_gt.json").write_text(json.dumps({"0": gt(1, 3), "1": gt(1), "2": gt(3, 1)}))
    (root / "test" / "000001" / "scene_gt.json").write_text(json.dumps({"0": gt(2, 2, 3), "10": gt(2), "9": gt()}))
    (root / "test" / "000003").mkdir()   # an object without a model: no target (bop_toolkit needs models)
    (root / "test" / "000003" / "scene_gt.json").write_text(json.dumps({"0": gt(4)}))


def test_targets_of_a_small_export_first_object_no_distractor(tmp_path):
    _export(tmp_path)
    targets = test_targets(tmp_path, "test")
    assert targets == [{"im_id": 0, "inst_count": 1, "obj_id": 1, "scene_id": 0},
                       {"im_id": 1, "inst_count": 1, "obj_id": 1, "scene_id": 0},
                       {"im_id": 0, "inst_count": 2, "obj_id": 2, "scene_id": 1},
                       {"im_id": 10, "inst_count": 1, "obj_id": 2, "scene_id": 1}]
    path = write_test_targets(tmp_path, "test")
    assert path.name == "test_targets_bop19.json" and load_test_targets(path) == targets
    assert list(json.loads(path.read_text())[0]) == ["im_id", "inst_count", "obj_id", "scene_id"]


def test_targets_round_trip_and_a_malformed_file_in_one_line(tmp_path):
    targets = [{"scene_id": 3, "im_id": 4, "obj_id": 4, "inst_count": 1}]
    assert load_test_targets(save_test_targets(tmp_path / "t.json", targets)) == targets
    (tmp_path / "bad.json").write_text('[{"im_id": 1}]')
    with pytest.raises(SpmError, match="expected a list of") as err:
        load_test_targets(tmp_path / "bad.json")
    assert "\n" not in str(err.value)

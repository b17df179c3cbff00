"""Importers refuse bad poses, intrinsics and tables with one line naming the file and
the row, and write nothing: every pose is checked before the first shard is written."""

import json

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from cli import data_cli
from spm_data.formats.bop.read import import_bop
from spm_data.errors import SpmError
from spm_data.formats.posed_folder import import_cvl, import_folder
from spm_data.core.poses import camera_pose
from spm_data.io.shards import list_shards

EULER = ["image", "rx", "ry", "rz", "tx", "ty", "tz"]
GOOD = [10, 20, 30, 0.01, -0.02, 0.5]


def posed_folder(root, header, rows, *, images=None):
    """PATH/poses.csv with ``header`` and ``rows`` (lists of cells), and a 32x40 PNG per row
    (``images``: which names to write; default every row's first cell)."""
    root.mkdir(parents=True, exist_ok=True)
    lines = [",".join(header)] + [",".join(str(v) for v in row) for row in rows]
    (root / "poses.csv").write_text("\n".join(lines) + "\n")
    for name in images if images is not None else [row[0] for row in rows]:
        cv2.imwrite(str(root / name), np.full((32, 40, 3), 200, np.uint8))
    return root / "poses.csv"


def refused(args, message, out, *, existed=False):
    """Run ``spm-data ARGS``: exit 1, stderr exactly ``error: MESSAGE``, nothing on stdout, no traceback,
    and nothing written to ``out`` (not created, or still empty when it ``existed``)."""
    r = CliRunner().invoke(data_cli, [str(a) for a in args])
    assert r.exit_code == 1, r.output
    assert r.exception is None or isinstance(r.exception, SystemExit), r.exc_info
    assert r.stdout == "" and "Traceback" not in r.output
    assert r.stderr == f"error: {message}\n", r.stderr
    if existed:
        assert list(out.iterdir()) == []
    else:
        assert not out.exists()


def good_rows(n):
    return [[f"i{k}.png", *GOOD] for k in range(n)]


# ---------------------------------------------------------------- folder: the table's columns

@pytest.mark.parametrize("header, message", [
    (["image", "rx", "ry", "rz", "tx", "ty"],
     "the header has no 'tz' column (columns: image, rx, ry, rz, tx, ty); the translation needs tx ty tz (in --unit)"),
    (["image", "rx", "ry", "tx", "ty", "tz"],
     "the header has no 'rz' column (columns: image, rx, ry, tx, ty, tz); a rotation needs all of rx ry rz"),
    (["image", "tx", "ty", "tz"],
     "the header has no rotation (columns: image, tx, ty, tz): give r11..r33, qw qx qy qz, or rx ry rz columns"),
    (["file", "rx", "ry", "rz", "tx", "ty", "tz"],
     "the header has no 'image' column (columns: file, rx, ry, rz, tx, ty, tz); add one naming each row's image file"),
    (EULER + ["fx", "fy"],
     "the header has no 'cx', 'cy' column (columns: image, rx, ry, rz, tx, ty, tz, fx, fy); give all of fx fy cx cy, "
     "or none of them and --fov"),
])
def test_folder_missing_columns(tmp_path, header, message):
    csv = posed_folder(tmp_path / "in", header, [["a.png"] + [1] * (len(header) - 1)])
    refused(["import", "folder", tmp_path / "in", "--out", tmp_path / "out", "--fov", "40"],
            f"{csv}:1: {message}", tmp_path / "out")


def test_folder_without_intrinsics_or_fov(tmp_path):
    csv = posed_folder(tmp_path / "in", EULER, good_rows(1))
    refused(["import", "folder", tmp_path / "in", "--out", tmp_path / "out"],
            f"{csv}:1: the header has no intrinsics (columns: image, rx, ry, rz, tx, ty, tz): add fx fy cx cy "
            "columns or pass --fov", tmp_path / "out")


# ---------------------------------------------------------------- folder: values in a row

K_HEADER = EULER + ["fx", "fy", "cx", "cy"]
K_GOOD = [50, 50, 19.5, 15.5]


@pytest.mark.parametrize("header, bad_row, message", [
    (EULER, ["b.png", "nan", 20, 30, 0.01, -0.02, 0.5], "column 'rx' is 'nan', not a finite number; fix that row"),
    (EULER, ["b.png", 10, 20, 30, 0.01, -0.02, "inf"], "column 'tz' is 'inf', not a finite number; fix that row"),
    (EULER, ["b.png", 10, 20, 30, "-Infinity", -0.02, 0.5],
     "column 'tx' is '-Infinity', not a finite number; fix that row"),
    (EULER, ["b.png", 10, "abc", 30, 0.01, -0.02, 0.5], "column 'ry' is not a number ('abc'); fix that row"),
    (EULER, ["b.png", 10, 20, 30, 0.01, "", 0.5], "column 'ty' is empty; expected a finite number, fix that row"),
    (EULER, ["b.png", 10, 20, 30, 0.01], "5 fields, the header has 7; fix that row"),
    (["image", "qw", "qx", "qy", "qz", "tx", "ty", "tz"], ["b.png", 1, 0, "NaN", 0, 0, 0, 0.5],
     "column 'qy' is 'NaN', not a finite number; fix that row"),
    (K_HEADER, ["b.png", *GOOD, 0, 50, 19.5, 15.5],
     "column 'fx' is '0'; expected a focal length > 0 pixels, fix that row"),
    (K_HEADER, ["b.png", *GOOD, 50, -5, 19.5, 15.5],
     "column 'fy' is '-5'; expected a focal length > 0 pixels, fix that row"),
    (K_HEADER, ["b.png", *GOOD, 50, "nan", 19.5, 15.5], "column 'fy' is 'nan', not a finite number; fix that row"),
    (K_HEADER, ["b.png", *GOOD, 50, 50, "inf", 15.5], "column 'cx' is 'inf', not a finite number; fix that row"),
    (K_HEADER, ["b.png", *GOOD, 50, 50, 19.5, ""], "column 'cy' is empty; expected a finite number, fix that row"),
])
def test_folder_bad_value_names_file_line_and_image(tmp_path, header, bad_row, message):
    good = [["a.png", *GOOD] + (K_GOOD if len(header) > 7 and "fx" in header else [])]
    if header[1] == "qw":
        good = [["a.png", 1, 0, 0, 0, 0, 0, 0.5]]
    csv = posed_folder(tmp_path / "in", header, good + [bad_row])
    refused(["import", "folder", tmp_path / "in", "--out", tmp_path / "out", "--fov", "40"],
            f"{csv}:3 (b.png): {message}", tmp_path / "out")


def test_folder_matrix_that_is_not_a_rotation(tmp_path):
    R, _ = camera_pose(30, 20, 0, 0.5)
    header = ["image"] + [f"r{i}{j}" for i in (1, 2, 3) for j in (1, 2, 3)] + ["tx", "ty", "tz"]
    csv = posed_folder(tmp_path / "in", header, [["a.png", *R.ravel(), 0, 0, 0.5],
                                                 ["b.png", *(2 * R).ravel(), 0, 0, 0.5]])
    refused(["import", "folder", tmp_path / "in", "--out", tmp_path / "out", "--fov", "40"],
            f"{csv}:3 (b.png): r11..r33 is not a rotation matrix (orthonormal within 0.0001, determinant +1); fix that "
            f"row",
            tmp_path / "out")


def test_folder_row_without_intrinsics_and_no_fov(tmp_path):
    csv = posed_folder(tmp_path / "in", K_HEADER, [["a.png", *GOOD, *K_GOOD], ["b.png", *GOOD, "", "", "", ""]])
    refused(["import", "folder", tmp_path / "in", "--out", tmp_path / "out"],
            f"{csv}:3 (b.png): no intrinsics: fill fx fy cx cy in that row or pass --fov", tmp_path / "out")


def test_folder_line_numbers_count_blank_lines_and_the_pose_is_checked_when_the_image_is_missing(tmp_path):
    root = tmp_path / "in"
    posed_folder(root, EULER, [], images=["a.png"])
    # line 1 header, 2 a.png, 3 blank, 4 gone.png (no such file; its pose is still checked)
    (root / "poses.csv").write_text("image,rx,ry,rz,tx,ty,tz\na.png,1,2,3,0,0,0.5\n\ngone.png,1,2,3,0,0,nan\n")
    refused(["import", "folder", root, "--out", tmp_path / "out", "--fov", "40"],
            f"{root / 'poses.csv'}:4 (gone.png): column 'tz' is 'nan', not a finite number; fix that row",
            tmp_path / "out")


def test_folder_bad_fov_and_a_folder_that_existed_stays_empty(tmp_path):
    posed_folder(tmp_path / "in", EULER, good_rows(2))
    (tmp_path / "out").mkdir()
    refused(["import", "folder", tmp_path / "in", "--out", tmp_path / "out", "--fov", "nan"],
            "--fov nan: expected a vertical field of view in (0, 180) degrees", tmp_path / "out", existed=True)


def test_folder_bad_row_after_a_full_shard_writes_nothing(tmp_path):
    """The bad row comes after enough good rows for two complete shards: still nothing is written."""
    csv = posed_folder(tmp_path / "in", EULER, good_rows(5) + [["bad.png", 1, 2, 3, 0, 0, "inf"]])
    with pytest.raises(SpmError) as err:
        import_folder(tmp_path / "in", tmp_path / "out", fov=40, frames_per_shard=2)
    assert str(err.value) == f"{csv}:7 (bad.png): column 'tz' is 'inf', not a finite number; fix that row"
    assert not (tmp_path / "out").exists()
    # The table fixed, the same call imports every row.
    posed_folder(tmp_path / "in", EULER, good_rows(6))
    summary, problems = import_folder(tmp_path / "in", tmp_path / "out", fov=40, frames_per_shard=2)
    assert summary.frames == 6 and not problems and len(list_shards(tmp_path / "out")) == 3


def test_cvl_one_bad_object_writes_nothing(tmp_path):
    posed_folder(tmp_path / "cvl" / "mug", EULER, good_rows(2))
    csv = posed_folder(tmp_path / "cvl" / "toy", EULER, [["a.png", 1, 2, 3, 0, 0, 500],
                                                         ["b.png", 1, 2, 3, "nan", 0, 500]])
    refused(["import", "cvl", tmp_path / "cvl", "--out", tmp_path / "out", "--fov", "40"],
            f"{csv}:3 (b.png): column 'tx' is 'nan', not a finite number; fix that row", tmp_path / "out")
    with pytest.raises(SpmError, match="column 'tx' is 'nan'"):
        import_cvl(tmp_path / "cvl", tmp_path / "out", fov=40)
    assert not (tmp_path / "out").exists()


# ---------------------------------------------------------------- COIL-100's assumed camera

@pytest.mark.parametrize("option, value, message", [
    ("--distance", "inf", "--distance inf: expected a finite camera distance > 0 metres"),
    ("--distance", "0", "--distance 0.0: expected a finite camera distance > 0 metres"),
    ("--elevation", "nan", "--elevation nan: expected a finite angle in [-90, 90] degrees"),
    ("--fov", "nan", "--fov nan: expected a vertical field of view in (0, 180) degrees"),
])
def test_coil100_assumed_camera_must_be_finite(tmp_path, option, value, message):
    coil = tmp_path / "coil-100"
    coil.mkdir()
    cv2.imwrite(str(coil / "obj1__0.png"), np.full((128, 128, 3), 120, np.uint8))
    refused(["import", "coil100", coil, "--out", tmp_path / "out", option, value], message, tmp_path / "out")


# ---------------------------------------------------------------- BOP

def bop_split(root, gts, cams=None):
    """Scenes 000000.. of train_pbr, one per (gt, cam) pair, each with one 120x160 image 000000."""
    K = [500.0, 0, 79.5, 0, 500.0, 59.5, 0, 0, 1]
    for s, gt in enumerate(gts):
        scene = root / "train_pbr" / f"{s:06d}"
        (scene / "rgb").mkdir(parents=True)
        cam = (cams or [None] * len(gts))[s] or {"0": {"cam_K": K, "depth_scale": 0.1}}
        (scene / "scene_camera.json").write_text(json.dumps(cam))
        (scene / "scene_gt.json").write_text(json.dumps(gt))
        cv2.imwrite(str(scene / "rgb" / "000000.png"), np.full((120, 160, 3), 90, np.uint8))
    return root


GOOD_GT = {"0": [{"cam_R_m2c": list(np.eye(3).ravel()), "cam_t_m2c": [10.0, -5.0, 700.0], "obj_id": 1}]}


def gt_with(**changes):
    entry = {**GOOD_GT["0"][0], **changes}
    return {"0": [GOOD_GT["0"][0], {k: v for k, v in entry.items() if v is not None}]}


@pytest.mark.parametrize("gt, message", [
    (gt_with(cam_t_m2c=[10.0, float("nan"), 700.0]),
     "cam_t_m2c has a non-finite value ([10, nan, 700]); expected 3 finite numbers, fix the file"),
    (gt_with(cam_R_m2c=[1, 0, 0, 0, float("inf"), 0, 0, 0, 1]),
     "cam_R_m2c has a non-finite value ([1, 0, 0, 0, inf, 0, 0, 0, 1]); expected 9 finite numbers, fix the file"),
    (gt_with(cam_R_m2c=None), "no 'cam_R_m2c'; expected 9 numbers, fix the file"),
    (gt_with(cam_t_m2c=[1.0, 2.0]), "cam_t_m2c has 2 values, expected 3; fix the file"),
    (gt_with(cam_R_m2c=[2, 0, 0, 0, 2, 0, 0, 0, 2]),
     "R = [2, 0, 0, 0, 2, 0, 0, 0, 2] is not a rotation matrix (orthonormal within 0.0001, determinant +1); fix the "
     "file"),
])
def test_bop_bad_pose_in_the_second_scene_writes_nothing(tmp_path, gt, message):
    root = bop_split(tmp_path / "bop", [GOOD_GT, gt])
    where = f"{root / 'train_pbr' / '000001' / 'scene_gt.json'}: image 0, object 1"
    refused(["import", "bop", root, "--out", tmp_path / "out"], f"{where}: {message}", tmp_path / "out")


@pytest.mark.parametrize("K, message", [
    ([0.0, 0, 79.5, 0, 500.0, 59.5, 0, 0, 1], "cam_K has fx = 0, fy = 500; expected fx, fy > 0, fix the file"),
    ([500.0, 0, float("inf"), 0, 500.0, 59.5, 0, 0, 1],
     "cam_K has a non-finite value ([500, 0, inf, 0, 500, 59.5, 0, 0, 1]); expected 9 finite numbers, fix the file"),
])
def test_bop_bad_intrinsics(tmp_path, K, message):
    root = bop_split(tmp_path / "bop", [GOOD_GT], [{"0": {"cam_K": K, "depth_scale": 0.1}}])
    where = f"{root / 'train_pbr' / '000000' / 'scene_camera.json'}: image 0"
    refused(["import", "bop", root, "--out", tmp_path / "out"], f"{where}: {message}", tmp_path / "out")


def test_bop_image_id_that_is_not_a_number(tmp_path):
    root = bop_split(tmp_path / "bop", [{"zero": GOOD_GT["0"]}])
    with pytest.raises(SpmError) as err:
        import_bop(root, tmp_path / "out")
    assert str(err.value) == (f"{root / 'train_pbr' / '000000' / 'scene_gt.json'}: image id 'zero' is not a number; "
                              "fix the file")
    assert not (tmp_path / "out").exists()

"""spm_data.formats.importing: what every importer shares: frame records checked before anything is
written, shards of imported frames (masks by threshold, crops), and the import report."""

import cv2
import numpy as np
import pytest

from spm_data.core.poses import camera_pose
from spm_data.errors import SpmError
from spm_data.formats.importing import (FrameRecord, check_fov_option, import_records, import_report, pose_problem,
                                        threshold_mask)
from spm_data.io.shards import list_shards, read_shard


def test_import_records_refuses_non_finite_records(tmp_path):
    R, t = camera_pose(0, 0, 0, 1.0)
    K = (100.0, 0, 63.5, 0, 100.0, 63.5, 0, 0, 1)
    good = FrameRecord("a.png", "c", "i", 0, tuple(R.ravel()), tuple(t), K)
    cases = [(good.__class__(**{**good.__dict__, "image": "b.png", "t": (0.0, 0.0, float("inf"))}),
              "b.png: the translation has a non-finite value (t = [0, 0, inf]); expected finite numbers; "
              "correct its pose or intrinsics (nothing was written)"),
             (good.__class__(**{**good.__dict__, "image": "c.png", "K": (float("nan"),) + K[1:]}),
              "c.png: the intrinsics have a non-finite value (K = [nan, 0, 63.5, 0, 100, 63.5, 0, 0, 1]); expected "
              "finite fx, fy, cx, cy; correct its pose or intrinsics (nothing was written)")]
    for bad, message in cases:
        with pytest.raises(SpmError) as err:
            import_records([good, bad], tmp_path / "out", source="test", prefix="t", frames_per_shard=1)
        assert str(err.value) == message
        assert not (tmp_path / "out").exists()


def test_threshold_mask_is_the_brightest_channel_over_the_threshold():
    rgb = np.array([[[0, 0, 0], [11, 0, 0], [0, 10, 10], [0, 0, 200]]], np.uint8)
    mask = threshold_mask(rgb, 10)
    assert mask.dtype == np.uint8 and mask.tolist() == [[0, 1, 0, 1]]


def test_pose_problem_says_what_cannot_be_imported():
    R, t = camera_pose(30, 20, 0, 0.5)
    K = np.array([[100.0, 0, 63.5], [0, 100.0, 63.5], [0, 0, 1]])
    assert pose_problem(R, t, K) is None and pose_problem(R, t) is None
    assert pose_problem(2 * np.eye(3), t) == ("R = [2, 0, 0, 0, 2, 0, 0, 0, 2] is not a rotation matrix (orthonormal "
                                              "within 0.0001, "
                                              "determinant +1)")
    assert pose_problem(np.full((3, 3), np.nan), t).startswith("the rotation has a non-finite value (R = [nan, nan")
    assert pose_problem(R, [0, 0, np.inf]) == ("the translation has a non-finite value (t = [0, 0, inf]); expected "
                                               "finite numbers")
    flat = K.copy()
    flat[1, 1] = 0
    assert pose_problem(R, t, flat) == "focal length fx = 100, fy = 0; expected fx, fy > 0 pixels"


@pytest.mark.parametrize("fov", [0.0, 180.0, -5.0, float("nan"), float("inf")])
def test_fov_option_must_lie_strictly_between_0_and_180(fov):
    with pytest.raises(SpmError, match=rf"^--fov {fov}: expected a vertical field of view in \(0, 180\) degrees$"):
        check_fov_option(fov)


def test_unreadable_images_are_skipped_and_reported(tmp_path):
    cv2.imwrite(str(tmp_path / "a.png"), np.full((32, 40, 3), 200, np.uint8))
    R, t = camera_pose(0, 0, 0, 1.0)
    K = (50.0, 0, 19.5, 0, 50.0, 15.5, 0, 0, 1)
    records = [FrameRecord(str(tmp_path / name), "c", "i", 0, tuple(R.ravel()), tuple(t), K)
               for name in ("a.png", "gone.png")]
    summary = import_records(records, tmp_path / "out", source="folder", prefix="t")
    assert summary.frames == 1 and [p.name for p in list_shards(tmp_path / "out")] == ["t-00000.h5"]
    mask = read_shard(tmp_path / "out" / "t-00000.h5", ["mask"])["mask"][0]
    assert mask.all()                                         # every pixel brighter than the threshold
    lines = import_report(summary, [("b.png", "missing view")]).splitlines()
    assert lines[0].startswith("imported 1 shard (1 frame) in ")
    assert lines[1:] == ["  skipped 2 images:", f"    {tmp_path / 'gone.png'}: {tmp_path / 'gone.png'}: no such file",
                         "    b.png: missing view"]
    with pytest.raises(SpmError, match="^nothing to import: no frames were found$"):
        import_records([], tmp_path / "none", source="folder", prefix="t")

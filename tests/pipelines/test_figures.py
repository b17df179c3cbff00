"""spm_data.pipelines.figures: contact sheets (frames with their pose axes) and occlusion
histograms, written whole as PNG, JPEG, PDF or SVG; bad output paths refused before any work."""

import cv2
import numpy as np
import pytest

from spm_data.pipelines.figures import AXIS_COLOURS, check_image_path, contact_sheet, draw_pose, occlusion_histogram
from spm_data.core.poses import intrinsics_from_fov
from spm_data.errors import ShardError, SpmError
from spm_data.io.shards import write_manifest, write_shard
from tests.helpers import make_arrays

COLOUR = (100, 150, 200)


@pytest.fixture
def shard(tmp_path):
    """5 frames of 32 x 40 pixels in one colour, without mask or occluder, the object behind
    the camera (so no axes are drawn), occlusion fractions 0, 0.1 .. 0.4; with a manifest."""
    a = make_arrays(n=5, h=32, w=40)
    a["rgb"][:] = COLOUR
    a["mask"][:] = 0
    a["occlusion_rects"][:] = 0
    a["K"][:] = intrinsics_from_fov(40, 40, 32)
    a["R"][:] = np.eye(3)
    a["t"][:] = (0.0, 0.0, -1.0)
    a["occlusion_fraction"] = np.arange(5, dtype=np.float32) / 10
    folder = tmp_path / "shards"
    folder.mkdir()
    path = write_shard(folder / "cup-00000.h5", a, {"renderer": "test", "seed": 0})
    write_manifest(folder)
    return path


def test_contact_sheet_is_a_grid_of_upscaled_frames(shard, tmp_path):
    out = contact_sheet(shard, tmp_path / "sheet.png", tile=80)          # 40 pixels wide: twice that
    assert out == tmp_path / "sheet.png" and sorted(p.name for p in tmp_path.iterdir()) == ["shards", "sheet.png"]
    sheet = cv2.cvtColor(cv2.imread(str(out)), cv2.COLOR_BGR2RGB)
    assert sheet.shape == (64 + 2, 5 * (80 + 2), 3)             # one row of 5 tiles, 2x upscaled, 2-pixel gaps
    assert (sheet[-2:] == 40).all() and (sheet[:, 80:82] == 40).all()     # the gaps
    assert (sheet[40:64, 10:80] == COLOUR).all()                # below the caption: the frame itself
    assert (sheet[:14, :80, 0] > 200).sum() > 20                # the caption, in white over the frame's red 100
    grid = cv2.imread(str(contact_sheet(shard, tmp_path / "grid.png", frames=4, columns=2, scale=1)))
    assert grid.shape == (2 * (32 + 2), 2 * (40 + 2), 3)


def test_contact_sheet_formats(shard, tmp_path):
    assert contact_sheet(shard, tmp_path / "s.jpg").read_bytes()[:3] == b"\xff\xd8\xff"
    assert contact_sheet(shard, tmp_path / "s.pdf").read_bytes()[:5] == b"%PDF-"
    assert b"<svg" in contact_sheet(shard, tmp_path / "s.svg").read_bytes()[:1000]


def test_draw_pose_draws_the_axes_from_k_r_t():
    K = np.array([[50.0, 0, 31.5], [0, 50, 31.5], [0, 0, 1]])
    image = np.zeros((64, 64, 3), np.uint8)
    out = draw_pose(image, K, np.eye(3), np.array([0, 0, 1.0]), 0.2)
    assert out is image
    # x ends 10 pixels right of the principal point, y 10 below it; z points at the camera (no length).
    assert tuple(image[32, 37]) == AXIS_COLOURS[0] and tuple(image[37, 32]) == AXIS_COLOURS[1]
    assert not image[:20].any() and not image[:, :25].any()
    behind = np.zeros((64, 64, 3), np.uint8)
    assert not draw_pose(behind, K, np.eye(3), np.array([0, 0, -1.0]), 0.2).any()


def test_occlusion_histogram_writes_an_image_of_the_figures_size(shard, tmp_path):
    out = occlusion_histogram(shard.parent, tmp_path / "hist.png")
    assert cv2.imread(str(out)).shape == (320, 600, 3)          # 6 x 3.2 inches at 100 dpi


def test_bad_image_paths_are_refused_before_any_work(shard, tmp_path):
    (tmp_path / "pictures").mkdir()
    (tmp_path / "notes").write_text("mine")
    for path, message in [
        (tmp_path / "pictures", f"{tmp_path / 'pictures'} is a folder; give an image file name such as "
                                f"{tmp_path / 'pictures' / 'sheet.png'}"),
        (tmp_path / "s.gif", f"{tmp_path / 's.gif'}: unsupported extension '.gif'; give a file name ending in "
                             ".png, .jpg, .jpeg, .pdf, .svg"),
        (tmp_path / "s", f"{tmp_path / 's'}: no extension; give a file name ending in .png, .jpg, .jpeg, .pdf, .svg"),
        (tmp_path / "notes" / "s.png", f"cannot write {tmp_path / 'notes' / 's.png'}: {tmp_path / 'notes'} is a "
                                       "file; give --out a path in a folder"),
    ]:
        with pytest.raises(SpmError) as info:
            contact_sheet(shard, path)
        assert str(info.value) == message
    assert check_image_path(tmp_path / "new" / "S.PNG") == tmp_path / "new" / "S.PNG"   # any case; nothing made
    assert sorted(p.name for p in tmp_path.iterdir()) == ["notes", "pictures", "shards"]


def test_a_shard_without_frames(tmp_path):
    write_shard(tmp_path / "empty.h5", make_arrays(n=0, h=4, w=4), {"renderer": "test", "seed": 0})
    with pytest.raises(ShardError, match="empty.h5: shard has no frames"):
        contact_sheet(tmp_path / "empty.h5", tmp_path / "s.png")
    assert not (tmp_path / "s.png").exists()


def test_a_sheet_of_an_outputs_field_in_false_colour(tmp_path):
    from spm_data.pipelines.figures import INSTANCE_COLOURS, false_colour

    a = make_arrays(n=2, h=16, w=20)
    a["t"][:] = (0.0, 0.0, -1.0)
    a["mask"][:] = 0
    a["instances"] = np.zeros((2, 16, 20), np.uint8)
    a["instances"][:, 10:14, 5:9] = 2
    path = write_shard(tmp_path / "x.h5", a, {"renderer": "test", "seed": 0})
    sheet = cv2.cvtColor(cv2.imread(str(contact_sheet(path, tmp_path / "ids.png", field="instances", tile=40))),
                         cv2.COLOR_BGR2RGB)
    assert (sheet[21:27, 11:17] == INSTANCE_COLOURS[2]).all() and (sheet[20:32, 0:8] == 0).all()
    with pytest.raises(ShardError, match="has no normals field; render it with \\[outputs\\] normals = true"):
        contact_sheet(path, tmp_path / "n.png", field="normals")
    n = np.zeros((2, 2, 3), np.float16)
    n[0, 0] = (0, 0, -1)
    np.testing.assert_array_equal(false_colour("normals", n, 0.25)[0], [[128, 128, 0], [0, 0, 0]])
    depth = false_colour("depth", np.array([[0.0, 1.0], [2.0, 3.0]], np.float32), 0.25)
    assert depth[0, 0, 0] == 0 and depth[0, 1, 0] == 255 and depth[1, 1, 0] == 55


def test_a_large_imported_frame_is_a_tile_of_the_set_size_with_axes_and_no_nan(tmp_path):
    """A 1080 x 1920 import leaves azimuth, elevation and roll NaN and has no object_size: the tile
    is 144 x 256, the caption says where the camera is (from R, t), the axes span a fifth of it."""
    from spm_data.core.poses import camera_pose

    a = make_arrays(n=2, h=1920, w=1080)
    a["rgb"][:] = COLOUR
    a["mask"][:] = 0
    a["mask"][:, 800:1100, 400:700] = 1
    a["occlusion_rects"][:] = 0
    a["K"][:] = [[1400.0, 0, 539.5], [0, 1400.0, 959.5], [0, 0, 1]]
    R, t = camera_pose(30.0, 20.0, 0.0, 2.5)
    a["R"][:], a["t"][:] = R, t
    for key in ("azimuth", "elevation", "roll", "distance"):
        a[key][:] = np.nan
    path = write_shard(tmp_path / "nerf-00000.h5", a, {"renderer": "none (imported)", "seed": 0})
    sheet = cv2.cvtColor(cv2.imread(str(contact_sheet(path, tmp_path / "s.png"))), cv2.COLOR_BGR2RGB)
    assert sheet.shape == (256 + 2, 2 * (144 + 2), 3)
    tile = sheet[:256, :144]
    for colour in AXIS_COLOURS[:2]:
        assert (np.abs(tile.astype(int) - colour).max(axis=2) < 30).sum() > 40   # long enough to see
    assert (np.abs(tile.astype(int) - (255, 220, 0)).max(axis=2) < 30).sum() > 60  # the mask's outline
    from spm_data.pipelines import figures

    frame = {"R": R, "t": t, "azimuth": np.nan, "elevation": np.nan, "distance": np.nan}
    assert figures._caption(frame, 3) == "#3 az30 el20 d2.50m"

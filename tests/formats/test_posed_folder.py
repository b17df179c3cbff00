"""spm_data.formats.posed_folder: a folder of images with a poses table (matrix, quaternion or
Euler rotations; intrinsics or --fov), and the CVL preset at 32, 128 and 256 px, grey and colour."""

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from cli import data_cli
from spm_data.core.poses import camera_pose
from spm_data.formats.posed_folder import import_cvl, import_folder
from spm_data.io.shards import list_shards, read_manifest, read_shard


def write_posed_folder(root, rows, header):
    root.mkdir(parents=True, exist_ok=True)
    lines = [",".join(header)]
    for name, values in rows:
        cv2.imwrite(str(root / name), np.full((32, 40, 3), 200, np.uint8))
        lines.append(",".join([name] + [str(v) for v in values]))
    (root / "poses.csv").write_text("\n".join(lines) + "\n")


def test_posed_folder_matrix_quaternion_and_euler(tmp_path):
    R, t = camera_pose(30, 20, 5, 0.5)
    from scipy.spatial.transform import Rotation

    q = Rotation.from_matrix(R).as_quat()  # x y z w
    e = Rotation.from_matrix(R).as_euler("ZYX", degrees=True)
    tm = t * 1000
    write_posed_folder(tmp_path / "m", [("a.png", list(R.ravel()) + list(tm) + [50, 50, 19.5, 15.5])],
                       ["image"] + [f"r{i}{j}" for i in (1, 2, 3) for j in (1, 2, 3)] + ["tx", "ty", "tz",
                                                                                      "fx", "fy", "cx", "cy"])
    write_posed_folder(tmp_path / "q", [("b.png", [q[3], q[0], q[1], q[2]] + list(tm))],
                       ["image", "qw", "qx", "qy", "qz", "tx", "ty", "tz"])
    write_posed_folder(tmp_path / "e", [("c.png", list(e) + list(tm))], ["image", "rx", "ry", "rz", "tx", "ty", "tz"])
    import_folder(tmp_path / "m", tmp_path / "o1", unit="mm")
    import_folder(tmp_path / "q", tmp_path / "o2", unit="mm", fov=40)
    import_folder(tmp_path / "e", tmp_path / "o3", unit="mm", fov=40, euler="ZYX")
    for out in ("o1", "o2", "o3"):
        d = read_shard(list_shards(tmp_path / out)[0])
        np.testing.assert_allclose(d["R"][0], R, atol=1e-9)
        np.testing.assert_allclose(d["t"][0], t, atol=1e-12)
        assert d["rgb"].shape == (1, 32, 40, 3) and d["source"][0] == "folder"
    np.testing.assert_allclose(read_shard(list_shards(tmp_path / "o1")[0])["K"][0],
                               [[50, 0, 19.5], [0, 50, 15.5], [0, 0, 1]])


def test_posed_folder_errors(tmp_path):
    write_posed_folder(tmp_path / "x", [("a.png", [1, 2, 3])], ["image", "tx", "ty", "tz"])
    r = CliRunner().invoke(data_cli, ["import", "folder", str(tmp_path / "x"), "--out", str(tmp_path / "o"),
                                      "--fov", "40"])
    assert r.exit_code == 1 and "no rotation" in r.output and r.output.count("\n") == 1
    assert not (tmp_path / "o").exists()


def test_cvl_preset(tmp_path):
    R, t = camera_pose(10, 10, 0, 0.6)
    header = ["image"] + [f"r{i}{j}" for i in (1, 2, 3) for j in (1, 2, 3)] + ["tx", "ty", "tz"]
    for obj in ("mug", "toy"):
        write_posed_folder(tmp_path / "cvl" / obj, [(f"{k}.png", list(R.ravel()) + list(t * 1000))
                                                    for k in range(3)], header)
    summary, problems = import_cvl(tmp_path / "cvl", tmp_path / "out", fov=40)
    assert summary.frames == 6 and not problems
    assert read_manifest(tmp_path / "out")["classes"] == {"mug": 3, "toy": 3}


@pytest.mark.parametrize("size", [32, 128, 256])
@pytest.mark.parametrize("grey", [True, False])
def test_cvl_layout_at_its_real_size_grey_or_colour(tmp_path, size, grey):
    """The CVL layout's images as they are: K from --fov and each image's own size, grey as RGB."""
    from spm_data.core.poses import intrinsics_from_fov

    R, t = camera_pose(30, 20, 0, 0.5)
    for obj in ("mug", "toy"):
        folder = tmp_path / "cvl" / obj
        folder.mkdir(parents=True)
        img = np.zeros((size, size, 3), np.uint8)
        cv2.circle(img, (size // 2, size // 2), size // 4, (40, 160, 250), -1)
        cv2.imwrite(str(folder / "v0.png"), img.max(axis=2) if grey else img[..., ::-1])
        (folder / "poses.csv").write_text("image," + ",".join(f"r{i}{j}" for i in (1, 2, 3) for j in (1, 2, 3))
                                          + ",tx,ty,tz\nv0.png," + ",".join(map(str, R.ravel()))
                                          + "," + ",".join(map(str, t * 1000)) + "\n")
    summary, problems = import_cvl(tmp_path / "cvl", tmp_path / "out", fov=40.0)
    assert summary.frames == 2 and problems == []
    d = read_shard(list_shards(tmp_path / "out")[0])
    assert d["rgb"].shape == (2, size, size, 3) and sorted(d["class_name"]) == ["mug", "toy"]
    np.testing.assert_allclose(d["K"][0], intrinsics_from_fov(40.0, size, size))
    np.testing.assert_allclose(d["R"][0], R, atol=1e-9)
    if grey:
        assert (d["rgb"][0] == d["rgb"][0][..., :1]).all()
    else:
        assert tuple(d["rgb"][0][size // 2, size // 2]) == (40, 160, 250)
    assert d["mask"][0].sum() > 0.1 * size * size


def test_a_fifo_or_a_folder_in_place_of_an_image_is_said_so_not_missing(tmp_path):
    import os

    write_posed_folder(tmp_path / "x", [("a.png", [0, 0, 0, 0, 0, 600]), ("b.png", [0, 0, 0, 0, 0, 600]),
                                        ("c.png", [0, 0, 0, 0, 0, 600])], ["image", "rx", "ry", "rz", "tx", "ty", "tz"])
    (tmp_path / "x" / "a.png").unlink()
    os.mkfifo(tmp_path / "x" / "a.png")   # read, it would wait for a writer for ever
    (tmp_path / "x" / "b.png").unlink()
    (tmp_path / "x" / "b.png").mkdir()
    summary, problems = import_folder(tmp_path / "x", tmp_path / "o", unit="mm", fov=40)
    said = dict(problems)
    assert summary.frames == 1 and set(said) == {str(tmp_path / "x" / "a.png"), str(tmp_path / "x" / "b.png")}
    assert said[str(tmp_path / "x" / "a.png")].endswith("a.png: is a FIFO, not a regular file; give an image file")
    assert said[str(tmp_path / "x" / "b.png")].endswith("b.png: is a folder, not an image file")

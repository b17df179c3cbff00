"""spm_data.formats.coil100: COIL-100 folders and archives (zip, tar of 16-bit PPM) imported
label by label, missing and unreadable views listed (the coil_folder fixture: tests/conftest.py)."""

import io
import tarfile
import zipfile

import numpy as np
import pytest

from spm_data.core.poses import wrap_degrees
from spm_data.formats.coil100 import import_coil100
from spm_data.io.shards import list_shards, read_manifest, read_shard
from tests.helpers import coil_image, png_bytes, ppm16


def test_coil100_folder_labels_value_by_value(coil_folder, tmp_path):
    summary, problems = import_coil100(coil_folder, tmp_path / "out", elevation=10.0, distance=0.8)
    assert ("obj12__45", "missing view") in problems
    assert any("README.txt" in p and "foreign file" in why for p, why in problems)
    skipped = [s for r in summary.results.values() for s in r["skipped"]]
    assert len(skipped) == 1 and "obj12__40.png" in skipped[0][0] and "not a readable image" in skipped[0][1]
    assert summary.frames == 72 + 70  # obj12: 71 files, one of them truncated (read, then skipped)
    data = {k: np.concatenate([read_shard(p)[k] for p in list_shards(tmp_path / "out")])
            for k in ("azimuth", "instance_id", "class_name", "pose", "label_measured", "mask", "rgb", "source",
                      "elevation", "distance")}
    assert len(data["azimuth"]) == 142
    i = np.flatnonzero((data["instance_id"] == 7) & (data["azimuth"] == 35))
    assert len(i) == 1
    i = i[0]
    assert data["class_name"][i] == "coil100-obj7" and data["source"][i] == "coil100"
    assert data["elevation"][i] == 10.0 and data["distance"][i] == 0.8
    np.testing.assert_allclose(data["pose"][i, 2], wrap_degrees(-(35 + 90)))
    np.testing.assert_allclose(data["pose"][i, 3:], [0, 0, 0.8], atol=1e-12)
    assert list(data["label_measured"][i]) == [False, False, True, False, False, False]
    np.testing.assert_array_equal(data["rgb"][i], coil_image(7, 35))
    np.testing.assert_array_equal(data["mask"][i], (coil_image(7, 35).max(axis=2) > 10).astype(np.uint8))


def test_coil100_zip_and_class_map(coil_folder, tmp_path):
    archive = tmp_path / "coil-100.zip"
    with zipfile.ZipFile(archive, "w") as zf:
        for p in sorted(coil_folder.iterdir()):
            zf.write(p, f"coil-100/{p.name}")
    (tmp_path / "map.csv").write_text("object,class\n7,cup\n12,car\n")
    summary, problems = import_coil100(archive, tmp_path / "out", classes_csv=tmp_path / "map.csv")
    assert read_manifest(tmp_path / "out")["classes"] == {"car": 70, "cup": 72}
    assert ("obj12__45", "missing view") in problems


def test_coil100_tar_of_16_bit_ppm(tmp_path):
    archive = tmp_path / "coil-100.tar.gz"
    with tarfile.open(archive, "w:gz") as tf:
        for angle in (0, 5, 355):
            data = ppm16(coil_image(3, angle))
            info = tarfile.TarInfo(f"coil-100/obj3__{angle}.ppm")
            info.size = len(data)
            tf.addfile(info, io.BytesIO(data))
    summary, problems = import_coil100(archive, tmp_path / "out")
    assert summary.frames == 3
    d = read_shard(list_shards(tmp_path / "out")[0])
    np.testing.assert_array_equal(d["rgb"][0], coil_image(3, 0))   # 16 bit scaled back to 8 exactly
    assert sorted(d["azimuth"]) == [0.0, 5.0, 355.0]
    assert len([p for p in problems if p[1] == "missing view"]) == 69


def _turntable(root, layout, size, grey, objects=(3, 8), views=range(72)):
    """Views of ``objects`` in a COIL layout ("coil100": obj{K}__{angle}.png, "coil20": obj{K}__{view}.png)
    at ``size`` px, grey (one channel) or colour."""
    import cv2

    root.mkdir(parents=True)
    for obj in objects:
        for view in views:
            img = cv2.resize(coil_image(obj, 5 * view), (size, size), interpolation=cv2.INTER_NEAREST)
            if grey:
                img = img.max(axis=2)
            number = 5 * view if layout == "coil100" else view
            cv2.imwrite(str(root / f"obj{obj}__{number}.png"), img if grey else img[..., ::-1])
    return root


@pytest.mark.parametrize("size", [32, 128, 256])
@pytest.mark.parametrize("grey", [True, False])
@pytest.mark.parametrize("layout", ["coil100", "coil20"])
def test_coil_layouts_at_their_real_size_grey_or_colour(tmp_path, layout, size, grey):
    from spm_data.core.poses import intrinsics_from_fov
    from spm_data.formats.coil100 import import_coil20

    root = _turntable(tmp_path / "set", layout, size, grey, views=range(0, 72, 7))
    run = import_coil100 if layout == "coil100" else import_coil20
    summary, problems = run(root, tmp_path / "out", fov=30.0)
    assert summary.frames == 2 * 11 and len([p for p in problems if p[1] == "missing view"]) == 2 * 61
    d = read_shard(list_shards(tmp_path / "out")[0])
    assert d["rgb"].shape == (22, size, size, 3) and d["rgb"].dtype == np.uint8
    np.testing.assert_allclose(d["K"][0], intrinsics_from_fov(30.0, size, size))   # K of the real size
    i = int(np.flatnonzero((d["instance_id"] == 8) & (d["azimuth"] == 35))[0])     # view 7: 35 degrees
    assert d["class_name"][i] == f"{layout}-obj8" and d["source"][i] == layout and d["path_index"][i] == 7
    np.testing.assert_allclose(d["pose"][i, 2], wrap_degrees(-(35 + 90)))
    if grey:
        assert (d["rgb"][i] == d["rgb"][i][..., :1]).all()    # grey -> RGB, the three channels equal
    assert d["mask"][i].any() and not d["mask"][i].all()


def test_coil20_numbers_name_views_and_coil100_says_when_it_sees_them(tmp_path):
    from spm_data.errors import SpmError
    from spm_data.formats.coil100 import coil_records

    root = _turntable(tmp_path / "coil20", "coil20", 32, True, objects=(1,), views=(0, 1, 2, 71))
    records, problems = coil_records(root, layout="coil20")
    assert [r.azimuth for r in records] == [0.0, 5.0, 10.0, 355.0]
    with pytest.raises(SpmError, match="numbered by view .* use spm-data import coil20"):
        coil_records(root, layout="coil100")
    (root / "obj1__72.png").write_bytes((root / "obj1__0.png").read_bytes())
    assert (str(root / "obj1__72.png"), "view 72 is not a view number in 0..71") in coil_records(
        root, layout="coil20")[1]


def test_coil20_says_when_it_sees_angles_and_a_view_given_twice_is_listed(tmp_path):
    from spm_data.errors import SpmError
    from spm_data.formats.coil100 import coil_records

    root = _turntable(tmp_path / "coil100", "coil100", 32, False, objects=(1,), views=(0, 1, 20))
    with pytest.raises(SpmError, match="numbered by angle .* use spm-data import coil100"):
        coil_records(root, layout="coil20")
    (root / "sub").mkdir()
    (root / "sub" / "obj1__5.png").write_bytes((root / "obj1__5.png").read_bytes())
    records, problems = coil_records(root, layout="coil100")
    assert len(records) == 3 and any("the same view as" in why for _, why in problems)


def test_image_sizes_read_each_archive_once(tmp_path, monkeypatch):
    """A tar.gz of 72 views: sizes from one pass over the archive, not one decompression per image."""
    import tarfile as tar_module

    from spm_data.formats.coil100 import coil_records

    archive = tmp_path / "coil-100.tar.gz"
    with tarfile.open(archive, "w:gz") as tf:
        for angle in range(0, 360, 5):
            data = png_bytes(coil_image(4, angle))
            info = tarfile.TarInfo(f"coil-100/obj4__{angle}.png")
            info.size = len(data)
            tf.addfile(info, io.BytesIO(data))
    opened = []
    real_open = tar_module.open
    monkeypatch.setattr(tar_module, "open", lambda *a, **k: opened.append(a[0]) or real_open(*a, **k))
    records, problems = coil_records(archive)
    assert len(records) == 72 and problems == [] and len(opened) == 2   # the listing, then the sizes


def _cli(args):
    from click.testing import CliRunner

    from cli import data_cli

    return CliRunner().invoke(data_cli, [str(a) for a in args])


def test_coil20_hostile_names_and_class_maps_are_one_line(tmp_path):
    """A 20-digit object number (an int64 overflow once), a binary class map, an id given twice, and a
    set whose every file is skipped: one error line each, exit 1, nothing written."""
    root = _turntable(tmp_path / "c", "coil20", 32, True, objects=(1,), views=(0,))
    huge = root / "obj99999999999999999999__0.png"
    huge.write_bytes((root / "obj1__0.png").read_bytes())
    binary, twice = tmp_path / "binary.csv", tmp_path / "twice.csv"
    binary.write_bytes(bytes(range(256)) * 4)
    twice.write_text("object,class\n1,cup\n1,mug\n")
    for path, message in ((binary, f"{binary}: not a text CSV of 'object,class' rows (UTF-8); give the class map "
                                   "as text"),
                          (twice, f"{twice}:3: object 1 is given a class twice (lines 2 and 3); keep one row per "
                                  "object")):
        r = _cli(["import", "coil20", root, "--out", tmp_path / "out", "--class-map", path])
        assert (r.exit_code, r.output) == (1, f"error: {message}\n")
    (root / "obj1__0.png").unlink()
    r = _cli(["import", "coil20", root, "--out", tmp_path / "out"])
    assert (r.exit_code, r.output) == (1, f"error: nothing to import: no frames were found (1 skipped; first: {huge}: "
                                          "object or view number has over 9 digits; not a COIL file name)\n")
    assert not (tmp_path / "out").exists()


def test_coil_images_with_nothing_above_the_threshold_are_skipped_not_written_empty(tmp_path):
    root = _turntable(tmp_path / "c", "coil20", 32, True, objects=(1,), views=(0, 1))
    (root / "obj1__1.png").write_bytes(png_bytes(np.zeros((32, 32, 3), np.uint8)))
    from spm_data.formats.coil100 import import_coil20

    summary, _ = import_coil20(root, tmp_path / "out")
    skipped = [s for r in summary.results.values() for s in r["skipped"]]
    assert summary.frames == 1 and skipped == [[str(root / "obj1__1.png"), f"{root / 'obj1__1.png'}: the object's "
                                                "mask is empty; give a mask that covers the object"]]

"""spm_data.formats.nerf: transforms.json captures (instant-ngp / nerfstudio) imported with the
exact pose, intrinsics and mask they describe; every malformed capture one line, nothing written."""

import json
import re

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from cli import data_cli
from spm_data.core.poses import K_to_corner_origin
from spm_data.errors import SpmError, SpmWarning
from spm_data.formats.nerf import import_nerf, nerf_records
from spm_data.io.shards import list_shards, read_shard
from tests.helpers import CENTER, SCALE, write_capture

@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    """A pyrender render of one cup instance (18 views at 64 x 64): rgb, mask, depth, K, R, t."""
    from spm_data.pipelines.render_jobs import load_run_specs, render_dataset
    from tests.helpers import SMALL_SPEC

    root = tmp_path_factory.mktemp("nerf-render")
    (root / "specs").mkdir()
    (root / "specs" / "cup.toml").write_text(SMALL_SPEC.format(cls="cup", seed=5).replace("instances = 2",
                                                                                          "instances = 1"))
    render_dataset(load_run_specs(all_classes=True, specs_dir=root / "specs"), root / "shards")
    parts = [read_shard(p) for p in list_shards(root / "shards")]
    return {k: np.concatenate([p[k] for p in parts]) for k in ("rgb", "mask", "depth", "K", "R", "t")}


def _imported(out):
    keys = ("rgb", "mask", "depth", "K", "R", "t", "source", "class_name", "label_measured")
    parts = [read_shard(p, keys) for p in list_shards(out)]   # depth: zeros where the capture has none
    return {k: np.concatenate([p[k] for p in parts]) for k in keys}


def test_a_rendered_class_written_as_a_capture_comes_back_with_the_same_pose_k_and_mask(rendered, tmp_path):
    d = rendered
    capture = write_capture(tmp_path / "cup-scan", d["rgb"], d["mask"], d["K"], d["R"], d["t"], depth=d["depth"])
    summary, problems = import_nerf(capture, tmp_path / "out", scale=SCALE, center=",".join(map(str, CENTER)))
    assert summary.frames == len(d["rgb"]) == 18 and problems == []
    got = _imported(tmp_path / "out")
    np.testing.assert_allclose(got["R"], d["R"], rtol=0, atol=1e-9)
    np.testing.assert_allclose(got["t"], d["t"], rtol=0, atol=1e-9)
    np.testing.assert_allclose(got["K"], d["K"], rtol=0, atol=1e-9)
    np.testing.assert_array_equal(got["mask"] > 0, d["mask"] > 0)
    np.testing.assert_array_equal(got["rgb"], d["rgb"])
    np.testing.assert_allclose(got["depth"], np.round(d["depth"] * 1000) / 1000, atol=1e-6)  # mm steps
    assert set(got["source"]) == {"nerf"} and set(got["class_name"]) == {"cup-scan"}
    assert got["label_measured"].all()


def test_per_frame_intrinsics_a_single_json_file_and_masks_from_a_folder(rendered, tmp_path):
    d = rendered
    capture = write_capture(tmp_path / "c", d["rgb"][:4], d["mask"][:4], d["K"][:4], d["R"][:4], d["t"][:4],
                            per_frame=True, alpha=False)
    (tmp_path / "masks").mkdir()
    for i in range(4):
        cv2.imwrite(str(tmp_path / "masks" / f"frame_{i:05d}.bmp"), d["mask"][i].astype(np.uint8) * 255)
    with pytest.raises(SpmError, match=r"frame 0 .*no mask: the image has no alpha channel.*--mask-dir"):
        nerf_records(capture)
    import_nerf(capture / "transforms.json", tmp_path / "out", scale=SCALE, center=CENTER, mask_dir=tmp_path / "masks",
                class_name="mug")
    got = _imported(tmp_path / "out")
    np.testing.assert_allclose(got["R"], d["R"][:4], atol=1e-9)
    np.testing.assert_allclose(got["K"], d["K"][:4], atol=1e-9)
    assert set(got["class_name"]) == {"mug"}
    np.testing.assert_array_equal(got["mask"] > 0, d["mask"][:4] > 0)   # a mask file of another suffix


def test_camera_angle_x_and_the_nerf_synthetic_split_files(tmp_path):
    (tmp_path / "lego" / "train").mkdir(parents=True)
    image = np.zeros((20, 30, 4), np.uint8)
    image[5:15, 10:20] = (90, 120, 150, 255)
    cv2.imwrite(str(tmp_path / "lego" / "train" / "r_0.png"), image)
    M = np.eye(4)
    M[:3, 3] = (0.0, 0.0, 4.0)   # 4 units in front of the object along +z, looking down -z at it
    for split in ("train", "test"):
        (tmp_path / "lego" / f"transforms_{split}.json").write_text(json.dumps(
            {"camera_angle_x": 0.6911112070083618, "frames": [{"file_path": "./train/r_0", "transform_matrix":
                                                               M.tolist()}]}))
    records, _ = nerf_records(tmp_path / "lego", scale=2.0)
    assert len(records) == 2
    K = np.array(records[0].K).reshape(3, 3)
    f = 15.0 / np.tan(0.6911112070083618 / 2)
    np.testing.assert_allclose(K, [[f, 0, 14.5], [0, f, 9.5], [0, 0, 1]])
    np.testing.assert_allclose(np.array(records[0].R).reshape(3, 3), np.diag([1.0, -1.0, -1.0]), atol=1e-12)
    np.testing.assert_allclose(records[0].t, [0.0, 0.0, 8.0], atol=1e-12)   # 4 units x 2 m


def test_lens_distortion_is_removed_to_the_pinhole_k(tmp_path):
    """An image taken through OpenCV's lens model, undistorted on import: straight back to the pinhole
    image (within interpolation) and exactly the pinhole K."""
    from spm_data.formats.capture_images import undistort

    h, w = 120, 160
    K = np.array([[140.0, 0, 79.5], [0, 140, 59.5], [0, 0, 1]])
    pinhole = np.zeros((h, w, 3), np.uint8)
    cv2.rectangle(pinhole, (40, 30), (120, 90), (255, 255, 255), -1)
    dist = np.array([-0.12, 0.03, 0.001, -0.002, 0.0])
    # Distort: for each distorted pixel, where it comes from in the pinhole image.
    u, v = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    points = cv2.undistortPoints(np.stack([u.ravel(), v.ravel()], 1)[:, None], K, dist, P=K)[:, 0]
    distorted = cv2.remap(pinhole, points[:, 0].reshape(h, w), points[:, 1].reshape(h, w), cv2.INTER_LINEAR)
    back = undistort(distorted, K, tuple(dist), fisheye=False, nearest=False)
    inner = (slice(10, h - 10), slice(10, w - 10))
    assert np.mean(np.abs(back[inner].astype(int) - pinhole[inner].astype(int)) > 64) < 0.01

    root = tmp_path / "lens"
    (root / "images").mkdir(parents=True)
    alpha = np.zeros((h, w), np.uint8)
    alpha[5:-5, 5:-5] = 255
    cv2.imwrite(str(root / "images" / "a.png"), np.dstack([distorted, alpha]))
    Kc = K_to_corner_origin(K)
    (root / "transforms.json").write_text(json.dumps({
        "fl_x": Kc[0, 0], "fl_y": Kc[1, 1], "cx": Kc[0, 2], "cy": Kc[1, 2], "w": w, "h": h,
        "k1": -0.12, "k2": 0.03, "p1": 0.001, "p2": -0.002,
        "frames": [{"file_path": "images/a.png", "transform_matrix": np.eye(4).tolist()}]}))
    import_nerf(root, tmp_path / "out")
    got = read_shard(list_shards(tmp_path / "out")[0])
    np.testing.assert_allclose(got["K"][0], K, atol=1e-12)
    np.testing.assert_array_equal(got["rgb"][0], back)


def _broken(tmp_path, edit, name="transforms.json"):
    root = tmp_path / "cap"
    (root / "images").mkdir(parents=True)
    cv2.imwrite(str(root / "images" / "a.png"), np.full((8, 8, 4), 255, np.uint8))
    data = {"fl_x": 10.0, "frames": [{"file_path": "images/a.png", "transform_matrix": np.eye(4).tolist()}]}
    edit(root, data)
    (root / name).write_text(json.dumps(data) if isinstance(data, dict) else data)
    return root


@pytest.mark.parametrize("edit, message", [
    (lambda root, d: d["frames"][0].pop("transform_matrix"),
     r"frame 0 \(images/a.png\): no transform_matrix; every frame needs its 4x4 camera-to-world matrix"),
    (lambda root, d: (root / "images" / "a.png").write_text("not a png"),
     r"frame 0 \(images/a.png\): image .*a.png: not a readable image"),
    (lambda root, d: d.update(camera_model="EQUIRECTANGULAR"),
     r"camera_model 'EQUIRECTANGULAR' is not one this importer can undistort"),
    (lambda root, d: d["frames"][0].update(transform_matrix=(2 * np.eye(4)).tolist()),
     r"last row is \[0.0, 0.0, 0.0, 2.0\]"),
    (lambda root, d: d["frames"][0]["transform_matrix"][0].__setitem__(0, 3.0),
     r"3x3 part is not a rotation"),
    (lambda root, d: d.pop("fl_x"), r"no intrinsics; expected fl_x"),
    (lambda root, d: d.update(w=9), r"the image is 8x8, the file says w = 9"),
    (lambda root, d: d["frames"][0].update(file_path="images/missing.png"), r"image .*missing.png is missing"),
    (lambda root, d: d.update(frames=[]), r"\"frames\" is empty"),
    (lambda root, d: d["frames"][0]["transform_matrix"][0].__setitem__(1, 2e-4),
     r"3x3 part is not a rotation"),                                       # beyond ROTATION_TOLERANCE
    (lambda root, d: d["frames"][0]["transform_matrix"][0].__setitem__(3, 1e308),
     r"a.png: the camera is inf m from the object \(t = .*\); expected at most 1e\+06 m; correct its pose"),
    (lambda root, d: d.update(fl_x=1e300), r"a.png: K = \[1e\+300, .*\] is not a camera"),
    (lambda root, d: d.update(k1=1e10), r"frame 0 \(images/a.png\): the lens \(1e\+10, 0, 0, 0, 0\) leaves 0% of "
                                        r"the undistorted image inside the photo, so its masks would be empty"),
    (lambda root, d: d["frames"][0].update(file_path="x" * 5000 + ".png"),
     r"^error: nothing to import: no frames were found \(1 skipped; first: frame 0 \(x{100}\.\.\. \(5004 "
     r"characters\)\): image .*x{10}\.\.\. \(50\d\d characters\) is missing\)$"),   # OSError 36 before
])
def test_every_malformed_capture_is_one_line_and_writes_nothing(tmp_path, edit, message):
    root = _broken(tmp_path, edit)
    out = tmp_path / "out"
    r = CliRunner().invoke(data_cli, ["import", "nerf", str(root), "--out", str(out)])
    assert r.exit_code == 1, r.output
    lines = r.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and "Traceback" not in r.output
    import re

    assert re.search(message, lines[0]), lines[0]
    assert not out.exists()


def test_paths_that_are_not_a_capture_are_one_line(tmp_path):
    png = tmp_path / "photo.png"
    cv2.imwrite(str(png), np.zeros((4, 4, 3), np.uint8))
    (tmp_path / "empty").mkdir()
    (tmp_path / "bad.json").write_text("{not json")
    for path, message in ((png, "not a transforms.json"), (tmp_path / "empty", "no transforms.json"),
                          (tmp_path / "bad.json", "not a JSON file"), (tmp_path / "nowhere", "no capture at")):
        r = CliRunner().invoke(data_cli, ["import", "nerf", str(path), "--out", str(tmp_path / "out")])
        assert r.exit_code == 1 and message in r.output and len(r.output.strip().splitlines()) == 1, r.output
    for option, value, message in (("--scale", "0", "--scale 0.0: expected"), ("--center", "1,2", "--center expects")):
        root = _broken(tmp_path / option.strip("-"), lambda root, d: None)
        r = CliRunner().invoke(data_cli, ["import", "nerf", str(root), "--out", str(tmp_path / "o"), option, value])
        assert r.exit_code == 1 and message in r.output, r.output
    assert not (tmp_path / "out").exists() and not (tmp_path / "o").exists()


def test_named_masks_win_over_alpha_and_an_opaque_alpha_is_no_mask(rendered, tmp_path):
    """Apps write RGBA PNGs opaque everywhere: such an alpha holds no mask. A frame's mask_path or
    --mask-dir is used before the alpha; an opaque alpha on its own is skipped and listed."""
    d = rendered
    rgb, mask = d["rgb"][:2], d["mask"][:2] > 0
    capture = write_capture(tmp_path / "c", rgb, np.ones_like(mask), d["K"][:2], d["R"][:2], d["t"][:2])
    with pytest.raises(SpmError, match=r"^nothing imported: every one of 2 frames was skipped \(2 skipped; first: "
                                       r".*frame_00000.png: its alpha channel is opaque everywhere, so it holds no "
                                       r"mask; .*; nothing was written$"):
        import_nerf(capture, tmp_path / "opaque", scale=SCALE, center=CENTER)
    assert not (tmp_path / "opaque").exists()
    (tmp_path / "masks").mkdir()
    for i in range(2):
        cv2.imwrite(str(tmp_path / "masks" / f"frame_{i:05d}.png"), mask[i].astype(np.uint8) * 255)
    import_nerf(capture, tmp_path / "out", scale=SCALE, center=CENTER, mask_dir=tmp_path / "masks")
    np.testing.assert_array_equal(_imported(tmp_path / "out")["mask"] > 0, mask)


def test_a_transforms_json_nested_100000_deep_is_one_line(tmp_path):
    (tmp_path / "cap").mkdir()
    (tmp_path / "cap" / "transforms.json").write_text("[" * 100_000 + "]" * 100_000)
    r = CliRunner().invoke(data_cli, ["import", "nerf", str(tmp_path / "cap"), "--out", str(tmp_path / "out")])
    assert r.exit_code == 1 and "Traceback" not in r.output, r.output
    assert r.output == f"error: {tmp_path / 'cap' / 'transforms.json'}: nested too deeply to be a transforms.json; " \
                       "give the capture's transforms.json\n"


def test_rotations_within_the_tolerance_are_stored_as_the_nearest_rotation(rendered, tmp_path):
    """A phone capture's matrices are orthonormal to ~1e-5: imported, stored exact (validate, run on
    every import by tests/conftest.py, wants 1e-6), and within 1e-4 of the file's."""
    d = rendered
    capture = write_capture(tmp_path / "c", d["rgb"][:3], d["mask"][:3], d["K"][:3], d["R"][:3], d["t"][:3])
    data = json.loads((capture / "transforms.json").read_text())
    for frame, error in zip(data["frames"], (3e-5, -6e-5, 9e-5)):
        frame["transform_matrix"][0][1] += error
    (capture / "transforms.json").write_text(json.dumps(data))
    import_nerf(capture, tmp_path / "out", scale=SCALE, center=CENTER)
    R = _imported(tmp_path / "out")["R"]
    assert np.abs(R @ R.transpose(0, 2, 1) - np.eye(3)).max() < 1e-14
    assert 1e-5 < np.abs(R - d["R"][:3]).max() < 1e-4
    from spm_data.pipelines.validate import validate_folder

    assert validate_folder(tmp_path / "out") == []


def test_missing_and_unreadable_images_are_listed_and_skipped_or_refused_with_strict(rendered, tmp_path):
    d = rendered
    capture = write_capture(tmp_path / "c", d["rgb"][:8], d["mask"][:8], d["K"][:8], d["R"][:8], d["t"][:8])
    for i in (1, 3, 4, 6):
        (capture / "images" / f"frame_{i:05d}.png").unlink()
    (capture / "images" / "frame_00007.png").write_bytes(b"not a png")
    with pytest.warns(SpmWarning) as said:
        summary, problems = import_nerf(capture, tmp_path / "out", scale=SCALE, center=CENTER)
    assert [str(w.message) for w in said] == [
        "skipping 5 of 8 frames whose image, mask or depth is missing or unreadable (frame 1 (images/frame_00001.png), "
        "frame 3 (images/frame_00003.png), frame 4 (images/frame_00004.png), ...); --strict refuses them"]
    assert summary.frames == 3 and [p[0] for p in problems] == [f"frame {i} (images/frame_{i:05d}.png)"
                                                                for i in (1, 3, 4, 6, 7)]
    assert problems[0][1] == f"image {capture / 'images' / 'frame_00001.png'} is missing"
    assert "not a readable image" in problems[4][1]
    r = CliRunner().invoke(data_cli, ["import", "nerf", str(capture), "--out", str(tmp_path / "o2"), "--strict"])
    assert r.exit_code == 1 and not (tmp_path / "o2").exists()
    assert re.fullmatch(r"error: 5 of 8 frames cannot be read \(frame 1 \(images/frame_00001.png\): image .* is "
                        r"missing; frame 3 .*; frame 4 .*; \.\.\.\); restore those files, or drop --strict to skip "
                        r"them\n", r.output), r.output


def test_without_scale_the_unit_is_said_and_recorded(rendered, tmp_path):
    d = rendered
    capture = write_capture(tmp_path / "c", d["rgb"][:2], d["mask"][:2], d["K"][:2], d["R"][:2], d["t"][:2])
    r = CliRunner().invoke(data_cli, ["import", "nerf", str(capture), "--out", str(tmp_path / "out")])
    assert r.exit_code == 0 and "warning: no --scale: the capture's world unit is taken as 1 m, so the reports' mm " \
                               "are thousandths of that unit; give --scale (metres per unit) for true mm\n" in r.stderr
    from spm_data.io.shards import read_attrs

    assert read_attrs(list_shards(tmp_path / "out")[0])["length_unit"] == "capture unit"
    import_nerf(capture, tmp_path / "metric", scale=SCALE, center=CENTER)
    assert read_attrs(list_shards(tmp_path / "metric")[0])["length_unit"] == "m"

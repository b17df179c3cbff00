"""Importers on fixtures in the datasets' real on-disk layouts, built here."""

import io
import json
import tarfile
import zipfile

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from cli import data_cli
from spm_data.formats.bop import export_bop, import_bop
from spm_data.formats.coil100 import import_coil100
from spm_data.io.images import parse_pnm
from spm_data.commands.merge import merge_folders
from spm_data.formats.posed_folder import import_cvl, import_folder
from spm_data.core.poses import camera_pose, wrap_degrees
from spm_data.commands.render_jobs import load_run_specs, render_dataset
from spm_data.io.shards import list_shards, read_manifest, read_shard


def coil_image(obj, angle):
    img = np.zeros((128, 128, 3), np.uint8)
    cv2.circle(img, (64, 64), 20 + obj % 10, (obj * 2 % 255, 100, angle % 255), -1)
    return img


def png_bytes(img):
    return cv2.imencode(".png", cv2.cvtColor(img, cv2.COLOR_RGB2BGR))[1].tobytes()


def ppm16(img, comment=b"# converted by a scanner tool\n"):
    """A 16-bit binary PPM with a comment and odd whitespace in its header."""
    data = (img.astype(">u2") * 257).tobytes()
    return b"P6\n" + comment + b"128  128\n\n65535\n" + data


OBJECTS = (7, 12)


@pytest.fixture(scope="module")
def coil_folder(tmp_path_factory):
    root = tmp_path_factory.mktemp("coil") / "coil-100"
    root.mkdir()
    for obj in OBJECTS:
        for angle in range(0, 360, 5):
            (root / f"obj{obj}__{angle}.png").write_bytes(png_bytes(coil_image(obj, angle)))
    (root / "obj12__45.png").unlink()                              # a missing view
    good = (root / "obj12__40.png").read_bytes()
    (root / "obj12__40.png").write_bytes(good[: len(good) // 2])   # a truncated PNG
    (root / "README.txt").write_text("COIL-100\n")                 # a foreign file
    return root


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


def test_pnm_parser_is_strict_about_truncation():
    img = coil_image(1, 0)
    np.testing.assert_array_equal(parse_pnm(ppm16(img)), img)
    from spm_data.io.images import ImageError

    with pytest.raises(ImageError, match="truncated"):
        parse_pnm(ppm16(img)[:-10])


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


def make_bop_scene(root):
    scene = root / "train_pbr" / "000000"
    for sub in ("rgb", "depth", "mask", "mask_visib"):
        (scene / sub).mkdir(parents=True)
    K = [500.0, 0, 79.5, 0, 500.0, 59.5, 0, 0, 1]
    gt = {"0": [{"cam_R_m2c": list(np.eye(3).ravel()), "cam_t_m2c": [10.0, -5.0, 700.0], "obj_id": 1},
                {"cam_R_m2c": list(camera_pose(30, 10, 0, 1)[0].ravel()), "cam_t_m2c": [-40.0, 20.0, 900.0],
                 "obj_id": 2}]}
    (scene / "scene_camera.json").write_text(json.dumps({"0": {"cam_K": K, "depth_scale": 0.1}}))
    (scene / "scene_gt.json").write_text(json.dumps(gt))
    cv2.imwrite(str(scene / "rgb" / "000000.jpg"), np.full((120, 160, 3), 90, np.uint8))
    cv2.imwrite(str(scene / "depth" / "000000.png"), np.full((120, 160), 7000, np.uint16))
    for g, (x0, x1) in enumerate([(20, 60), (70, 140)]):
        m = np.zeros((120, 160), np.uint8)
        m[30:90, x0:x1] = 255
        cv2.imwrite(str(scene / "mask" / f"000000_{g:06d}.png"), m)
        m[30:60, x0:x1] = 0  # top half hidden
        cv2.imwrite(str(scene / "mask_visib" / f"000000_{g:06d}.png"), m)
    return gt


def test_bop_import_two_objects(tmp_path):
    gt = make_bop_scene(tmp_path / "bop")
    summary, problems = import_bop(tmp_path / "bop", tmp_path / "out")
    d = read_shard(list_shards(tmp_path / "out")[0])
    assert summary.frames == 2 and not problems
    assert list(d["class_name"]) == ["bop-obj1", "bop-obj2"]
    np.testing.assert_allclose(d["t"][0], [0.010, -0.005, 0.700])
    np.testing.assert_allclose(d["R"][1].ravel(), gt["0"][1]["cam_R_m2c"])
    np.testing.assert_allclose(d["depth"][0], 0.7, rtol=1e-6)   # 7000 x 0.1 mm
    assert d["mask"][0].sum() == 60 * 40 and d["visible_mask"][0].sum() == 30 * 40
    np.testing.assert_allclose(d["occlusion_fraction"], [0.5, 0.5])
    summary, _ = import_bop(tmp_path / "bop", tmp_path / "crops", crop=64)
    c = read_shard(list_shards(tmp_path / "crops")[0])
    assert c["rgb"].shape == (2, 64, 64, 3)
    # The crop's K still projects the object's centre ray onto the mask's centre.
    ys, xs = np.nonzero(c["mask"][0])
    assert abs(xs.mean() - 31.5) < 2 and abs(ys.mean() - 31.5) < 2


def test_render_export_import_round_trip(small_specs_dir, tmp_path):
    render_dataset(load_run_specs(["cup"], specs_dir=small_specs_dir), tmp_path / "r", limit=10)
    counts = export_bop(tmp_path / "r", tmp_path / "bop")
    assert counts["frames"] == 10 and counts["objects"] == 2 and not counts["without_model"]
    info = json.loads((tmp_path / "bop" / "models" / "models_info.json").read_text())
    assert set(info) == {"1", "2"} and 200 < info["1"]["diameter"] < 450  # mm; 0.25 m objects
    gt_info = json.loads((tmp_path / "bop" / "train" / "000000" / "scene_gt_info.json").read_text())
    assert gt_info["0"][0]["visib_fract"] == 1.0
    import_bop(tmp_path / "bop", tmp_path / "back", split="train")
    src = {k: np.concatenate([read_shard(p)[k] for p in list_shards(tmp_path / "r")]) for k in ("R", "t", "mask", "depth", "K")}
    back = {k: np.concatenate([read_shard(p)[k] for p in list_shards(tmp_path / "back")]) for k in ("R", "t", "mask", "depth", "K")}
    # Export groups frames by object instance; the render is already in that order.
    np.testing.assert_allclose(back["R"], src["R"], atol=1e-12)
    np.testing.assert_allclose(back["t"], src["t"], atol=1e-12)
    np.testing.assert_array_equal(back["mask"], src["mask"])
    np.testing.assert_allclose(back["depth"], src["depth"], atol=0.00005 + 1e-7)  # 0.1 mm steps
    np.testing.assert_allclose(back["K"], src["K"])
    assert not (tmp_path / "bop.partial").exists()


def test_merge_keeps_every_frame_once(small_specs_dir, coil_folder, tmp_path):
    render_dataset(load_run_specs(all_classes=True, specs_dir=small_specs_dir), tmp_path / "syn", limit=12)
    import_coil100(coil_folder, tmp_path / "coil")
    merge_folders([tmp_path / "syn", tmp_path / "coil"], tmp_path / "m", frames_per_shard=50,
                  renames={"coil100-obj7": "cup"})
    manifest = read_manifest(tmp_path / "m")
    assert manifest["frames"] == 24 + 142
    assert [s["folder"] for s in manifest["sources"]] == [str(tmp_path / "syn"), str(tmp_path / "coil")]
    assert manifest["classes"]["cup"] == 12 + 72 and "coil100-obj7" not in manifest["classes"]
    sizes = {e["file"]: e["frames"] for e in manifest["shards"]}
    assert sizes == {"merged-128x128-00000.h5": 50, "merged-128x128-00001.h5": 50, "merged-128x128-00002.h5": 42,
                     "merged-64x64-00000.h5": 24}  # full shards per image size, the last of each partial

    def identities(folders):
        rows = []
        for folder in folders:
            for p in list_shards(folder):
                d = read_shard(p, ["instance_name", "pose", "rgb"])
                rows += [(n, tuple(np.round(y, 9)), hash(img.tobytes()))
                         for n, y, img in zip(d["instance_name"], d["pose"], d["rgb"])]
        return sorted(rows)

    merged, inputs = identities([tmp_path / "m"]), identities([tmp_path / "syn", tmp_path / "coil"])
    assert merged == inputs and len(set(merged)) == len(merged)  # every frame exactly once


def test_merge_filters_sources_and_refuses_mixed_schemas(small_specs_dir, coil_folder, tmp_path):
    render_dataset(load_run_specs(["cup"], specs_dir=small_specs_dir), tmp_path / "syn", limit=6)
    import_coil100(coil_folder, tmp_path / "coil")
    merge_folders([tmp_path / "syn", tmp_path / "coil"], tmp_path / "only", sources=["synthetic"])
    assert read_manifest(tmp_path / "only")["frames"] == 6
    import h5py

    with h5py.File(list_shards(tmp_path / "syn")[0], "a") as f:
        f.attrs["schema_version"] = 0
    r = CliRunner().invoke(data_cli, ["merge", str(tmp_path / "syn"), str(tmp_path / "coil"), "--out",
                                      str(tmp_path / "bad")])
    assert r.exit_code == 1 and "schema version 0 has no checksums, so it cannot be verified" in r.output
    assert not (tmp_path / "bad").exists()


def test_cli_import_reports_skips_and_resumes(coil_folder, tmp_path):
    args = ["import", "coil100", str(coil_folder), "--out", str(tmp_path / "o")]
    r = CliRunner().invoke(data_cli, args)
    assert r.exit_code == 0, r.output
    assert "imported 1 shards (142 frames)" in r.output
    assert "skipped 3 images:" in r.output and "missing view" in r.output and "foreign file" in r.output
    assert "truncated" in r.output
    r = CliRunner().invoke(data_cli, args)
    assert "1 already complete" in r.output
    r = CliRunner().invoke(data_cli, ["export", "bop", str(tmp_path / "o"), "--out", str(tmp_path / "b")])
    assert r.exit_code == 0 and "exported 142 frames of 2 objects in 2 scenes" in r.output
    assert "no mesh for 2 objects" in r.output
    r = CliRunner().invoke(data_cli, ["export", "bop", str(tmp_path / "o"), "--out", str(tmp_path / "b")])
    assert r.exit_code == 1 and "not empty" in r.output


def test_bop_poses_survive_import_then_export_exactly(tmp_path):
    gt = make_bop_scene(tmp_path / "bop")
    import_bop(tmp_path / "bop", tmp_path / "ours")
    export_bop(tmp_path / "ours", tmp_path / "again")
    exported = []
    for scene in sorted((tmp_path / "again" / "train").iterdir()):
        for objs in json.loads((scene / "scene_gt.json").read_text()).values():
            exported += [(o["cam_R_m2c"], o["cam_t_m2c"]) for o in objs]
    original = [(o["cam_R_m2c"], o["cam_t_m2c"]) for o in gt["0"]]
    assert len(exported) == 2
    for (R0, t0), (R1, t1) in zip(original, exported):
        np.testing.assert_allclose(R1, R0, atol=1e-12)
        np.testing.assert_allclose(t1, t0, atol=1e-9)   # mm -> m -> mm
    cams = json.loads((tmp_path / "again" / "train" / "000000" / "scene_camera.json").read_text())
    np.testing.assert_allclose(cams["0"]["cam_K"], [500.0, 0, 79.5, 0, 500.0, 59.5, 0, 0, 1])
    info = json.loads((tmp_path / "again" / "train" / "000000" / "scene_gt_info.json").read_text())
    assert info["0"][0]["visib_fract"] == 0.5

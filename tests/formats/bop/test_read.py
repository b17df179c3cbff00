"""spm_data.formats.bop.read: import of BOP scenes (poses, depth, visible masks, crops, names), and
round trips through the export."""

import json

import cv2
import numpy as np

from spm_data.formats.bop.read import import_bop
from spm_data.formats.bop.export import export_bop
from spm_data.core.poses import camera_pose
from spm_data.pipelines.render_jobs import load_run_specs, render_dataset
from spm_data.io.shards import list_shards, read_shard


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
    np.testing.assert_allclose(d["R"][1].ravel(), gt["0"][1]["cam_R_m2c"], atol=1e-12)  # the nearest rotation
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
    src = {k: np.concatenate([read_shard(p)[k] for p in list_shards(tmp_path / "r")]) for k in ("R", "t", "mask",
                                                                                                "depth", "K")}
    back = {k: np.concatenate([read_shard(p)[k] for p in list_shards(tmp_path / "back")]) for k in ("R", "t", "mask",
                                                                                                    "depth", "K")}
    # Export groups frames by object instance; the render is already in that order.
    np.testing.assert_allclose(back["R"], src["R"], atol=1e-12)
    np.testing.assert_allclose(back["t"], src["t"], atol=1e-12)
    np.testing.assert_array_equal(back["mask"], src["mask"])
    np.testing.assert_allclose(back["depth"], src["depth"], atol=0.00005 + 1e-7)  # 0.1 mm steps
    np.testing.assert_allclose(back["K"], src["K"])
    assert not (tmp_path / "bop.partial").exists()
    # objects.json gives the names back, not bop-objN.
    names = [{k: [str(v) for p in list_shards(folder) for v in read_shard(p)[k]]
              for k in ("class_name", "instance_name", "instance_id")} for folder in (tmp_path / "r",
                                                                                      tmp_path / "back")]
    assert names[1] == names[0] and names[1]["class_name"][0] == "cup"
    import_bop(tmp_path / "bop", tmp_path / "renamed", split="train", classes_csv=_csv(tmp_path, "2,mug\n"))
    renamed = read_shard(list_shards(tmp_path / "renamed")[0], ["class_name", "instance_name"])
    assert set(map(str, renamed["class_name"])) == {"cup", "mug"}
    assert "bop-obj2" not in set(map(str, renamed["instance_name"]))


def _csv(folder, text):
    (folder / "map.csv").write_text(text)
    return folder / "map.csv"


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


def test_an_8_bit_depth_png_is_said_so(tmp_path):
    """Issue 47: an 8-bit colour depth PNG was skipped as "depth is 160x120, image is 160x120"."""
    from spm_data.errors import SpmError

    make_bop_scene(tmp_path / "bop")
    depth = tmp_path / "bop" / "train_pbr" / "000000" / "depth" / "000000.png"
    for image, channels in ((np.full((120, 160, 3), 70, np.uint8), 3), (np.full((120, 160), 70, np.uint8), 1)):
        cv2.imwrite(str(depth), image)
        try:
            summary, _ = import_bop(tmp_path / "bop", tmp_path / f"out{channels}")
            said = " ".join(why for r in summary.results.values() for _, why in r.get("skipped", []))
        except SpmError as exc:   # every frame skipped: the command's one line
            said = str(exc)
        assert f"depth is an 8-bit image with {channels} channel(s); expected one 16-bit channel" in said, said
        assert "image is 160x120" not in said

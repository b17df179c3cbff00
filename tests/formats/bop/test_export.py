"""spm_data.formats.bop.export: export as BOP's own tools read it (K convention, models, splits,
COCO, exact meshes, object ids)."""

import json
import shutil

import cv2
import numpy as np
import pytest
import trimesh
from click.testing import CliRunner

from cli import data_cli
from spm_data.formats.bop.read import import_bop
from spm_data.formats.bop.export import export_bop
from spm_data.formats.coco import load_scene_gt_coco, rle_to_mask
from spm_data.errors import MeshError, SpmError
from spm_data.formats.ply import load_ply
from spm_data.core.poses import cv_to_gl_camera_to_world
from spm_data.render.pyrender_backend import _offscreen
from spm_data.pipelines.render_jobs import load_run_specs, render_dataset
from spm_data.io.folders import open_folder
from spm_data.io.shards import list_shards, read_attrs, read_shard, write_shard
from tests.helpers import write_small_specs


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    """Cup and box, 8 frames each (pyrender, 64 x 64), exported as a PBR split; made once for the
    module. Read-only for tests."""
    root = tmp_path_factory.mktemp("exported")
    specs = write_small_specs(root / "specs")
    render_dataset(load_run_specs(["cup", "box"], specs_dir=specs), root / "r", limit=8)
    export_bop(root / "r", root / "bop", split="train_pbr")
    return root / "r", root / "bop"


def scenes(root, split="train_pbr"):
    for scene in sorted((root / split).iterdir()):
        cams = json.loads((scene / "scene_camera.json").read_text())
        gts = json.loads((scene / "scene_gt.json").read_text())
        for im in sorted(gts, key=int):
            yield scene, int(im), np.reshape(cams[im]["cam_K"], (3, 3)), gts[im][0]


def rendered_mask(model, K, gt, size):
    """The object's mask rendered by pyrender, whose IntrinsicsCamera takes K as BOP writes
    it (principal point counted from the pixel corner), from BOP's files alone."""
    import pyrender as pr

    R = np.reshape(gt["cam_R_m2c"], (3, 3))
    t = np.asarray(gt["cam_t_m2c"]) / 1000.0
    material = pr.MetallicRoughnessMaterial(doubleSided=True)
    prim = pr.Primitive(positions=(model["vertices"] / 1000.0).astype(np.float32),
                        indices=model["faces"].astype(np.uint32), material=material)
    scene = pr.Scene()
    scene.add(pr.Mesh([prim]))
    scene.add(pr.IntrinsicsCamera(K[0, 0], K[1, 1], K[0, 2], K[1, 2], znear=0.01, zfar=100.0),
              pose=cv_to_gl_camera_to_world(R, t))
    # The process's one renderer of this size: deleting an EGL renderer breaks later ones.
    depth = _offscreen(pr, size, size).render(scene, flags=pr.RenderFlags.DEPTH_ONLY)
    return depth > 0


def test_k_is_written_in_bop_convention_and_reads_back_exactly(exported, tmp_path):
    shards, bop = exported
    ours = read_shard(list_shards(shards)[0], ["K"])["K"][0]
    for _, _, K, _ in scenes(bop):
        np.testing.assert_array_equal(K[:2, 2], ours[:2, 2] + 0.5)   # 31.5 -> 32.0 at 64 px
    camera = json.loads((bop / "camera.json").read_text())
    assert (camera["cx"], camera["cy"]) == (32.0, 32.0)
    import_bop(bop, tmp_path / "back", split="train_pbr")
    back = np.concatenate([read_shard(p, ["K"])["K"] for p in list_shards(tmp_path / "back")])
    assert len(back) == 16 and (back == ours).all()   # exact, not close


def test_bop_projection_re_renders_our_masks_to_the_pixel(exported):
    _, bop = exported
    differing, shifted, frames = 0, 0, 0
    for scene, im, K, gt in scenes(bop):
        model = load_ply(bop / "models" / f"obj_{gt['obj_id']:06d}.ply")
        ours = cv2.imread(str(scene / "mask" / f"{im:06d}_000000.png"), cv2.IMREAD_UNCHANGED) > 0
        differing += int((rendered_mask(model, K, gt, 64) != ours).sum())
        old = K.copy()
        old[:2, 2] -= 0.5  # the OpenCV K the export wrote before
        shifted += int((rendered_mask(model, old, gt, 64) != ours).sum())
        frames += 1
    assert frames == 16 and differing == 0
    assert shifted > 50  # the half pixel matters, so the comparison above can fail


def test_models_have_unit_normals_texture_and_eval_copies(exported):
    _, bop = exported
    info = json.loads((bop / "models" / "models_info.json").read_text())
    assert set(info) == {"1", "2", "3", "4"}
    for obj in info:
        model = load_ply(bop / "models" / f"obj_{int(obj):06d}.ply")
        np.testing.assert_allclose(np.linalg.norm(model["normals"], axis=1), 1.0, atol=1e-6)
        assert model["texture_file"] == f"obj_{int(obj):06d}.png"
        assert cv2.imread(str(bop / "models" / model["texture_file"])).shape[2] == 3
        assert model["colors"].shape == model["vertices"].shape and model["uv"].min() >= 0
        lo, size = model["vertices"].min(axis=0), np.ptp(model["vertices"], axis=0)
        entry = info[obj]
        np.testing.assert_allclose(lo, [entry["min_x"], entry["min_y"], entry["min_z"]], atol=1e-3)
        np.testing.assert_allclose(size, [entry["size_x"], entry["size_y"], entry["size_z"]], atol=1e-3)
        assert max(size) == pytest.approx(250.0, abs=1e-3)   # 0.25 m objects, in mm
        ev = load_ply(bop / "models_eval" / f"obj_{int(obj):06d}.ply")
        edges = np.linalg.norm(ev["vertices"][ev["faces"][:, 0]] - ev["vertices"][ev["faces"][:, 1]], axis=1)
        # Resampled: about one vertex per 2 % of the diameter, spread over the whole surface.
        assert edges.max() < 0.1 * entry["diameter"] and len(ev["vertices"]) > 500
        np.testing.assert_allclose(ev["vertices"].min(axis=0), lo, atol=0.03 * entry["diameter"])
        np.testing.assert_allclose(np.linalg.norm(ev["normals"], axis=1), 1.0, atol=1e-5)
    assert json.loads((bop / "models_eval" / "models_info.json").read_text()) == info


def test_pbr_splits_are_jpeg_other_splits_png(exported, tmp_path):
    shards, bop = exported
    pbr = sorted(p.name for p in (bop / "train_pbr" / "000000" / "rgb").iterdir())
    assert pbr and all(name.endswith(".jpg") for name in pbr)
    jpg = cv2.imread(str(bop / "train_pbr" / "000000" / "rgb" / pbr[0]))[..., ::-1]
    ours = np.concatenate([read_shard(p, ["rgb"])["rgb"] for p in list_shards(shards)])
    errors = [np.abs(jpg.astype(int) - rgb).mean() for rgb in ours]
    source = ours[int(np.argmin(errors))]
    assert sorted(errors)[1] > 5 * min(errors)   # one frame is its source
    # JPEG at quality 95 (BlenderProc's), exactly as OpenCV encodes that frame.
    again = cv2.imencode(".jpg", source[..., ::-1].copy(), [cv2.IMWRITE_JPEG_QUALITY, 95])[1]
    np.testing.assert_array_equal(cv2.imdecode(again, cv2.IMREAD_COLOR)[..., ::-1], jpg)
    export_bop(shards, tmp_path / "png", split="test")
    assert all(p.suffix == ".png" for p in (tmp_path / "png" / "test" / "000000" / "rgb").iterdir())


def test_scene_gt_coco_decodes_to_our_visible_masks(small_specs_dir, tmp_path):
    render_dataset(load_run_specs(["cup"], specs_dir=small_specs_dir), tmp_path / "r", limit=6)
    CliRunner().invoke(data_cli, ["occlude", str(tmp_path / "r"), "--out", str(tmp_path / "o"),
                                  "--max", "0.6", "--copies", "1", "--seed", "2"], catch_exceptions=False)
    export_bop(tmp_path / "o", tmp_path / "bop")
    checked = 0
    for scene in sorted((tmp_path / "bop" / "train").iterdir()):
        coco = load_scene_gt_coco(scene / "scene_gt_coco.json")
        info = json.loads((scene / "scene_gt_info.json").read_text())
        # every object of the dataset, as bop_toolkit lists them
        assert [c["id"] for c in coco["categories"]] == [1, 2]
        for ann in coco["annotations"]:
            image = next(i for i in coco["images"] if i["id"] == ann["image_id"])
            assert (scene / image["file_name"]).is_file()
            im = ann["image_id"]
            visible = cv2.imread(str(scene / "mask_visib" / f"{im:06d}_000000.png"), cv2.IMREAD_UNCHANGED) > 0
            np.testing.assert_array_equal(rle_to_mask(ann["segmentation"]), visible)
            x, y, w, h = info[str(im)][0]["bbox_obj"]   # bop_toolkit's: w = x_max - x_min
            assert ann["area"] == visible.sum() and ann["bbox"] == [x, y, w + 1, h + 1]  # COCO's, amodal
            checked += 1
    assert checked == 6


def test_occluded_export_has_occluder_depth_so_bop_visibility_agrees(small_specs_dir, tmp_path):
    DEPTH_SCALE = 0.1  # every depth here is within 6.5 m: the finest scale (bop_gt.DEPTH_SCALES)
    from spm_data.io.folders import open_folder

    render_dataset(load_run_specs(["cup"], specs_dir=small_specs_dir), tmp_path / "r", limit=6)
    CliRunner().invoke(data_cli, ["occlude", str(tmp_path / "r"), "--out", str(tmp_path / "o"),
                                  "--min", "0.2", "--max", "0.6", "--copies", "1"], catch_exceptions=False)
    export_bop(tmp_path / "o", tmp_path / "bop")
    scene_of, seen = {}, {}
    for path in open_folder(tmp_path / "o").shards:   # the export's order: scene per object, frames in turn
        d = read_shard(path, ["instance_name", "depth", "mask"])
        for name, d_model, mask in zip(d["instance_name"], d["depth"], d["mask"]):
            scene = scene_of.setdefault(name, len(scene_of))
            im = seen[scene] = seen.get(scene, -1) + 1
            sdir = tmp_path / "bop" / "train" / f"{scene:06d}"
            d_test = cv2.imread(str(sdir / "depth" / f"{im:06d}.png"), cv2.IMREAD_UNCHANGED) * DEPTH_SCALE / 1000
            # bop_toolkit's visibility ("bop19", 15 mm tolerance), from depth alone.
            visib = (((d_model - d_test) <= 0.015) | (d_test == 0)) & (d_model > 0)
            info = json.loads((sdir / "scene_gt_info.json").read_text())[str(im)][0]
            assert visib.sum() / (mask > 0).sum() == pytest.approx(info["visib_fract"], abs=1e-12)
            assert info["visib_fract"] < 0.85 and info["px_count_valid"] == (mask > 0).sum()
    assert sum(n + 1 for n in seen.values()) == 6


def glb_box(path, extents):
    trimesh.creation.box(extents=extents).export(path)


def mesh_spec(folder, files, symmetries=""):
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "user.toml").write_text(f"""
class = "user"
[mesh]
source = "files"
files = {json.dumps(files)}
{symmetries}
[camera]
azimuth = [0, 10, 5]
elevation = 0
distances = [0.7]
[image]
width = 48
height = 48
[render]
renderer = "pyrender"
""")
    return folder / "user.toml"


def _as_older_shard(folder, out_file):
    """The folder's first shard as spm wrote it before the mesh store: no ``mesh`` field, no meshes/."""
    shard = open_folder(folder).shards[0]
    arrays = read_shard(shard)
    arrays.pop("mesh")
    attrs = {k: v for k, v in read_attrs(shard).items() if k not in ("schema_version", "frames", "height", "width")}
    out_file.parent.mkdir(parents=True, exist_ok=True)
    return write_shard(out_file, arrays, attrs)


def test_export_reads_the_rendered_mesh_from_the_store_whatever_happens_to_the_file(tmp_path):
    spec = mesh_spec(tmp_path / "project", ["meshes/*.glb"], 'symmetries = ["z/90"]')
    (tmp_path / "project" / "meshes").mkdir()
    glb_box(tmp_path / "project" / "meshes" / "a.glb", [0.2, 0.3, 0.2])
    render_dataset(load_run_specs(spec_files=[spec]), tmp_path / "r")
    glb_box(tmp_path / "project" / "meshes" / "a.glb", [0.2, 0.3, 0.25])   # edited after the render
    export_bop(tmp_path / "r", tmp_path / "bop")
    info = json.loads((tmp_path / "bop" / "models" / "models_info.json").read_text())["1"]
    # The glTF box as rendered, 0.3 tall (y up), stands 250 mm tall on its z axis; its declared 4-fold turn is exported.
    assert info["size_z"] == pytest.approx(250.0) and info["size_x"] == pytest.approx(250 * 2 / 3)
    assert len(info["symmetries_discrete"]) == 3 and "symmetries_continuous" not in info
    shutil.rmtree(tmp_path / "r" / "meshes")   # a folder copied without its store is not whole
    r = CliRunner().invoke(data_cli, ["export", "bop", str(tmp_path / "r"), "--out", str(tmp_path / "bop2")])
    assert r.exit_code == 1 and len(r.output.strip().splitlines()) == 1
    assert "missing from the folder's mesh store" in r.output and str(tmp_path / "r" / "meshes") in r.output
    assert not (tmp_path / "bop2").exists() and not (tmp_path / "bop2.partial").exists()


def test_older_shards_find_meshes_by_the_spec_folder_and_refuse_changed_ones(tmp_path, monkeypatch):
    spec = mesh_spec(tmp_path / "project", ["meshes/*.glb"], 'symmetries = ["z/90"]')
    (tmp_path / "project" / "meshes").mkdir()
    glb_box(tmp_path / "project" / "meshes" / "a.glb", [0.2, 0.3, 0.2])
    # A different file at the same relative path from the folder the export runs in.
    (tmp_path / "elsewhere" / "meshes").mkdir(parents=True)
    glb_box(tmp_path / "elsewhere" / "meshes" / "a.glb", [0.5, 0.1, 0.1])
    render_dataset(load_run_specs(spec_files=[spec]), tmp_path / "r")
    old = _as_older_shard(tmp_path / "r", tmp_path / "old" / "a.h5")
    monkeypatch.chdir(tmp_path / "elsewhere")
    export_bop(old, tmp_path / "bop")
    info = json.loads((tmp_path / "bop" / "models" / "models_info.json").read_text())["1"]
    assert info["size_z"] == pytest.approx(250.0) and info["size_x"] == pytest.approx(250 * 2 / 3)
    glb_box(tmp_path / "project" / "meshes" / "a.glb", [0.2, 0.3, 0.25])   # edited after the render
    r = CliRunner().invoke(data_cli, ["export", "bop", str(old), "--out", str(tmp_path / "bop2")])
    assert r.exit_code == 1 and len(r.output.strip().splitlines()) == 1
    assert str(tmp_path / "project" / "meshes" / "a.glb") in r.output
    assert "has changed since it was rendered" in r.output
    assert str(tmp_path / "project") in r.output and "'meshes/a.glb'" in r.output
    assert not (tmp_path / "bop2").exists() and not (tmp_path / "bop2.partial").exists()


def test_export_spec_dir_points_at_moved_meshes_of_older_shards(tmp_path):
    spec = mesh_spec(tmp_path / "project", ["meshes/a.glb"])
    (tmp_path / "project" / "meshes").mkdir()
    glb_box(tmp_path / "project" / "meshes" / "a.glb", [0.2, 0.3, 0.2])
    render_dataset(load_run_specs(spec_files=[spec]), tmp_path / "r")
    old = _as_older_shard(tmp_path / "r", tmp_path / "old" / "a.h5")
    (tmp_path / "project").rename(tmp_path / "moved")
    export_bop(tmp_path / "r", tmp_path / "from-store")   # the store needs no spec folder
    with pytest.raises(MeshError, match="not found .*'meshes/a.glb' relative to the spec folder"):
        export_bop(old, tmp_path / "bop")
    export_bop(old, tmp_path / "bop", meshes_from=tmp_path / "moved")
    assert (tmp_path / "bop" / "models" / "obj_000001.ply").is_file()
    assert (tmp_path / "bop" / "models" / "obj_000001.ply").read_bytes() == \
        (tmp_path / "from-store" / "models" / "obj_000001.ply").read_bytes()


def test_split_must_be_one_folder_name_and_meshes_from_a_folder(small_specs_dir, tmp_path):
    render_dataset(load_run_specs(["cup"], specs_dir=small_specs_dir), tmp_path / "r", limit=2)
    for split in ("../evil", "", "a/b", ".hidden"):
        r = CliRunner().invoke(data_cli, ["export", "bop", str(tmp_path / "r"), "--out", str(tmp_path / "bop"),
                                          "--split", split])
        assert r.exit_code == 1 and "expected one folder name" in r.output, (split, r.output)
        assert len(r.output.strip().splitlines()) == 1
    r = CliRunner().invoke(data_cli, ["export", "bop", str(tmp_path / "r"), "--out", str(tmp_path / "bop"),
                                      "--meshes-from", str(tmp_path / "nowhere")])
    assert r.exit_code == 1 and "--meshes-from" in r.output and "no such folder" in r.output
    assert not (tmp_path / "evil").exists() and not (tmp_path / "bop").exists()


def test_a_cluttered_export_keeps_the_rendered_depth_and_visible_masks(tmp_path):
    DEPTH_SCALE = 0.1  # every depth here is within 6.5 m: the finest scale (bop_gt.DEPTH_SCALES)
    from tests.pipelines.test_render_frames import CLUTTERED

    folder = tmp_path / "specs"
    folder.mkdir()
    (folder / "c.toml").write_text(CLUTTERED.format(cls="c").replace('frames_per_shard = 8', 'frames_per_shard = 6'))
    render_dataset(load_run_specs(all_classes=True, specs_dir=folder), tmp_path / "r", limit=6)
    export_bop(tmp_path / "r", tmp_path / "bop")
    d = read_shard(list_shards(tmp_path / "r")[0], ["depth", "mask", "visible_mask", "instance_id"])
    seen = {}
    for i, inst in enumerate(d["instance_id"]):
        scene = sorted(set(d["instance_id"])).index(inst)
        im = seen[scene] = seen.get(scene, -1) + 1
        sdir = tmp_path / "bop" / "train" / f"{scene:06d}"
        depth = cv2.imread(str(sdir / "depth" / f"{im:06d}.png"), cv2.IMREAD_UNCHANGED) * DEPTH_SCALE / 1000
        # The distractors' own depth in front of the target, not a flat stand-in.
        np.testing.assert_allclose(depth, d["depth"][i], atol=DEPTH_SCALE / 1000)
        visib = cv2.imread(str(sdir / "mask_visib" / f"{im:06d}_000000.png"), cv2.IMREAD_UNCHANGED) > 0
        np.testing.assert_array_equal(visib, d["visible_mask"][i] > 0)
        info = json.loads((sdir / "scene_gt_info.json").read_text())[str(im)][0]
        assert info["visib_fract"] == pytest.approx(d["visible_mask"][i].sum() / d["mask"][i].sum())


# --------------------------------------------------------------------------- ids, depth scale, cameras

def test_object_ids_are_stable_across_exports_and_named_in_objects_json(small_specs_dir, tmp_path):
    render_dataset(load_run_specs(["cup", "box"], specs_dir=small_specs_dir), tmp_path / "all", limit=8)
    render_dataset(load_run_specs(["cup"], specs_dir=small_specs_dir), tmp_path / "cup", limit=4)
    export_bop(tmp_path / "all", tmp_path / "bop_all")
    objects = json.loads((tmp_path / "bop_all" / "objects.json").read_text())
    # Sorted by class, then instance: box first although the cup was rendered first.
    assert [(v["class"], v["instance_id"]) for v in objects.values()] == [("box", 0), ("box", 1), ("cup", 0), ("cup",
                                                                                                               1)]
    assert list(objects) == ["1", "2", "3", "4"] and objects["3"]["instance"] == "cup-000"
    export_bop(tmp_path / "cup", tmp_path / "bop_cup_alone")
    export_bop(tmp_path / "cup", tmp_path / "bop_cup", ids_from=tmp_path / "bop_all")
    alone = json.loads((tmp_path / "bop_cup_alone" / "objects.json").read_text())
    kept = json.loads((tmp_path / "bop_cup" / "objects.json").read_text())
    assert list(alone) == ["1", "2"]                                  # numbered afresh alone,
    assert kept == {"3": objects["3"], "4": objects["4"]}              # kept with ids_from
    gt = json.loads((tmp_path / "bop_cup" / "train" / "000002" / "scene_gt.json").read_text())
    assert gt["0"][0]["obj_id"] == 3
    with pytest.raises(SpmError, match="objects.json: no such file"):
        export_bop(tmp_path / "cup", tmp_path / "bop_bad", ids_from=tmp_path / "cup")


def test_depth_beyond_6_5_m_gets_a_coarser_scale_not_clipped(tmp_path):
    (tmp_path / "far.toml").write_text('class = "far"\n[mesh]\ngenerator = "cup"\ninstances = 1\n'
                                       '[camera]\nazimuth = [0, 5, 5]\nelevation = 0\ndistances = [7.0]\n'
                                       '[image]\nwidth = 64\nheight = 64\nfov = 5.0\n[render]\nrenderer = "pyrender"\n')
    render_dataset(load_run_specs(spec_files=[tmp_path / "far.toml"]), tmp_path / "r")
    export_bop(tmp_path / "r", tmp_path / "bop")
    ours = read_shard(list_shards(tmp_path / "r")[0], ["depth"])["depth"]
    sdir = tmp_path / "bop" / "train" / "000000"
    cams = json.loads((sdir / "scene_camera.json").read_text())
    for im in range(2):
        scale = cams[str(im)]["depth_scale"]
        depth = cv2.imread(str(sdir / "depth" / f"{im:06d}.png"), cv2.IMREAD_UNCHANGED) * scale / 1000
        assert scale == 0.2 and ours[im].max() > 6.8
        np.testing.assert_allclose(depth, ours[im], atol=scale / 2000 + 1e-6)   # half a step, not 0.4 m
    assert json.loads((tmp_path / "bop" / "camera.json").read_text())["depth_scale"] == 0.2


def test_scene_camera_has_world_to_camera_poses(exported):
    _, bop = exported
    for scene, im, _, gt in scenes(bop):
        cam = json.loads((scene / "scene_camera.json").read_text())[str(im)]
        # One object a scene, in its own frame: world to camera is model to camera.
        assert cam["cam_R_w2c"] == gt["cam_R_m2c"] and cam["cam_t_w2c"] == gt["cam_t_m2c"]
        assert cam["depth_scale"] == 0.1


def test_two_exports_with_source_date_epoch_are_byte_identical(exported, tmp_path, monkeypatch):
    """An export records a date (COCO's date_created): SOURCE_DATE_EPOCH fixes it, so the same
    folder exports to the same bytes, file for file."""
    rendered, _ = exported
    monkeypatch.setenv("SOURCE_DATE_EPOCH", "1764115200")   # 2025-11-26 00:00 UTC
    export_bop(rendered, tmp_path / "a", split="train_pbr")
    export_bop(rendered, tmp_path / "b", split="train_pbr")
    files = sorted(p.relative_to(tmp_path / "a") for p in (tmp_path / "a").rglob("*") if p.is_file())
    assert files and files == sorted(p.relative_to(tmp_path / "b") for p in (tmp_path / "b").rglob("*") if p.is_file())
    assert all((tmp_path / "a" / f).read_bytes() == (tmp_path / "b" / f).read_bytes() for f in files)
    coco = json.loads(next((tmp_path / "a" / "train_pbr").glob("*/scene_gt_coco.json")).read_text())
    assert coco["info"]["date_created"] == "2025-11-26 00:00:00+00:00"
    monkeypatch.setenv("SOURCE_DATE_EPOCH", "yesterday")
    with pytest.raises(SpmError, match=r"^SOURCE_DATE_EPOCH='yesterday': expected whole seconds since 1970"):
        export_bop(rendered, tmp_path / "c", split="train_pbr")
    assert not (tmp_path / "c").exists()

"""spm_data.formats.bop.scene: every object of a frame in its scene, the target first, each with
its masks, scene_gt_info entry and COCO annotation; a target without a mesh keeps image-only
ground truth; in a merged folder each frame's own occlusion (2-D rectangles, 3-D distractors or
none), whatever order the folders were merged in."""

import itertools
import json

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from cli import data_cli
from spm_data.pipelines.merge import merge_folders
from spm_data.core.poses import K_to_corner_origin, intrinsics_from_fov
from spm_data.errors import SpmError
from spm_data.formats.bop.read import import_bop
from spm_data.formats.bop.export import export_bop
from spm_data.formats.bop.ids import frame_ids, load_objects
from spm_data.formats.bop.scene import SceneWriter, load_scene_file, save_scene_file
from spm_data.formats.coco import load_scene_gt_coco, rle_to_mask
from spm_data.io.folders import open_folder
from spm_data.io.shards import list_shards, read_shard, shard_layout
from spm_data.pipelines.render_jobs import load_run_specs, render_dataset
from tests.pipelines.test_render_frames import CLUTTERED
from tests.helpers import write_small_specs

FRAMES = 6


@pytest.fixture(scope="module")
def cluttered(tmp_path_factory):
    """6 frames of a cup with 2 distractors each (pyrender, 128 x 128), exported with and without
    the distractors. Read-only for tests."""
    root = tmp_path_factory.mktemp("scene")
    (root / "specs").mkdir()
    (root / "specs" / "c.toml").write_text(CLUTTERED.format(cls="c").replace("frames_per_shard = 8",
                                                                              f"frames_per_shard = {FRAMES}"))
    render_dataset(load_run_specs(all_classes=True, specs_dir=root / "specs"), root / "r", limit=FRAMES)
    export_bop(root / "r", root / "bop")
    export_bop(root / "r", root / "targets", include_distractors=False)
    return root / "r", root / "bop", root / "targets"


def png(path):
    return cv2.imread(str(path), cv2.IMREAD_UNCHANGED) > 0


def frames(bop):
    """(scene folder, im, scene_gt entries, scene_gt_info entries) per image, in export order."""
    for sdir in sorted((bop / "train").iterdir()):
        gts = json.loads((sdir / "scene_gt.json").read_text())
        infos = json.loads((sdir / "scene_gt_info.json").read_text())
        for im in sorted(gts, key=int):
            yield sdir, int(im), gts[im], infos[im]


def test_every_distractor_is_an_object_of_its_frame_after_its_target(cluttered):
    shards, bop, _ = cluttered
    d = read_shard(list_shards(shards)[0], ["instance_id", "instances", "distractor_mesh", "visible_mask"])
    objects = {int(k): v for k, v in json.loads((bop / "objects.json").read_text()).items()}
    targets = {k for k, v in objects.items() if v.get("role") != "distractor"}
    assert len(targets) == 2 and min(set(objects) - targets) > max(targets)   # distractors numbered after
    seen = {}
    for sdir, im, gts, infos in frames(bop):
        i = [k for k, inst in enumerate(d["instance_id"]) if sorted(set(d["instance_id"])).index(inst) ==
             int(sdir.name)][im]   # the shard frame: scenes by target, images in frame order
        assert gts[0]["obj_id"] == int(sdir.name) + 1
        assert len(gts) == len(infos) == 1 + (d["distractor_mesh"][i] >= 0).sum()
        coco = load_scene_gt_coco(sdir / "scene_gt_coco.json")
        anns = [a for a in coco["annotations"] if a["image_id"] == im]
        for k, (gt, info) in enumerate(zip(gts, infos)):
            name = f"{im:06d}_{k:06d}.png"
            full, visib = png(sdir / "mask" / name), png(sdir / "mask_visib" / name)
            assert (visib <= full).all() and info["px_count_visib"] == visib.sum()
            # Seen where the render saw it (instances: 1 the target, 2 + k distractor k; a pixel centre
            # on an edge may go either way). Also seen, by bop19's 15 mm tolerance, where another
            # distractor is in front by less: never over the target, which is behind them all.
            rendered = d["instances"][i] == (1 if k == 0 else 1 + k)
            extra = visib & ~rendered
            assert (rendered & ~visib).sum() <= 2 and (extra & (d["instances"][i] < 2)).sum() <= 2
            if k == 0:
                assert extra.sum() <= 2
            if k:
                assert gt["obj_id"] not in targets and objects[gt["obj_id"]]["role"] == "distractor"
            if visib.any():
                ann = next(a for a in anns if a["category_id"] == gt["obj_id"])
                np.testing.assert_array_equal(rle_to_mask(ann["segmentation"]), visib)
        assert len(anns) == sum(1 for info in infos if info["px_count_visib"] > 0)
        seen[int(sdir.name)] = seen.get(int(sdir.name), 0) + 1
    assert sum(seen.values()) == FRAMES


def test_without_distractors_the_targets_ground_truth_is_the_same(cluttered):
    _, bop, targets = cluttered
    both = list(frames(bop))
    alone = list(frames(targets))
    assert len(both) == len(alone) == FRAMES
    for (sdir, im, gts, infos), (_, im2, gts2, infos2) in zip(both, alone):
        assert len(gts2) == 1 and gts2[0] == gts[0] and infos2[0] == infos[0] and im == im2
    objects = (json.loads((folder / "objects.json").read_text()) for folder in (targets, bop))
    assert next(objects).keys() < next(objects).keys()   # the distractors are objects of the export with them



def test_a_cluttered_frames_masks_are_what_the_export_counts(tmp_path):
    # Its amodal mask is the numpy silhouette, drawn by the export's own rules (llvmpipe's): for a
    # target inside the image, px_count_all is its pixel count and visib_fract 1 - occlusion_fraction
    # to the last bit. Before the silhouette followed them, frame 9 was a pixel off (2633 pixels in the
    # shard, 2634 in px_count_all: a pixel centre on a triangle's edge).
    (tmp_path / "specs").mkdir()
    (tmp_path / "specs" / "c.toml").write_text(CLUTTERED.format(cls="c").replace("views = 12", "views = 48"))
    render_dataset(load_run_specs(all_classes=True, specs_dir=tmp_path / "specs"), tmp_path / "r", limit=12)
    export_bop(tmp_path / "r", tmp_path / "bop", include_distractors=False)
    ids, k = frame_ids(tmp_path / "r"), 0
    for path in open_folder(tmp_path / "r").shards:
        d = read_shard(path, ["mask", "visible_mask", "occlusion_fraction"])
        for mask, visible, occlusion in zip(d["mask"] > 0, d["visible_mask"] > 0, d["occlusion_fraction"]):
            sdir, im = tmp_path / "bop" / "train" / f"{int(ids.scene_id[k]):06d}", int(ids.im_id[k])
            info = json.loads((sdir / "scene_gt_info.json").read_text())[str(im)][0]
            assert not (mask[[0, -1]].any() or mask[:, [0, -1]].any())   # inside the image
            assert (info["px_count_all"], info["px_count_visib"]) == (mask.sum(), visible.sum()), k
            assert np.float32(1.0 - info["visib_fract"]) == occlusion, k
            np.testing.assert_array_equal(png(sdir / "mask" / f"{im:06d}_000000.png"), mask)
            k += 1
    assert k == 12

def frame_data(h=16, w=20):
    mask = np.zeros((1, h, w), np.uint8)
    mask[0, 4:10, 5:12] = 1
    visible = mask.copy()
    visible[0, 4:6] = 0
    return {"rgb": np.zeros((1, h, w, 3), np.uint8), "depth": mask * np.float32(0.5), "mask": mask,
            "visible_mask": visible, "K": np.array([[[20.0, 0, 9.5], [0, 20.0, 7.5], [0, 0, 1]]]),
            "R": np.eye(3)[None], "t": np.array([[0, 0, 0.5]])}


def test_a_target_without_a_mesh_keeps_its_image_masks(tmp_path):
    written = []
    writer = SceneWriter(tmp_path / "train", ".png", lambda path, a: written.append(path) or path.write_bytes(
        cv2.imencode(".png", a)[1].tobytes()), set())
    data = frame_data()
    writer.add_frame(data, 0, [(3, None, data["R"][0], data["t"][0])])
    writer.finish([3, 4])
    sdir = tmp_path / "train" / "000002"
    np.testing.assert_array_equal(png(sdir / "mask" / "000000_000000.png"), data["mask"][0] > 0)
    np.testing.assert_array_equal(png(sdir / "mask_visib" / "000000_000000.png"), data["visible_mask"][0] > 0)
    info = json.loads((sdir / "scene_gt_info.json").read_text())["0"][0]
    assert info["px_count_all"] == 42 and info["px_count_visib"] == 28 and info["bbox_obj"] == [5, 4, 6, 5]
    gt = json.loads((sdir / "scene_gt.json").read_text())["0"]
    assert gt == [{"cam_R_m2c": np.eye(3).ravel().tolist(), "cam_t_m2c": [0.0, 0.0, 500.0], "obj_id": 3}]
    cam = json.loads((sdir / "scene_camera.json").read_text())["0"]
    assert cam["cam_K"][2] == 10.0 and cam["depth_scale"] == 0.1   # BOP's pixel-corner convention
    assert [c["id"] for c in load_scene_gt_coco(sdir / "scene_gt_coco.json")["categories"]] == [3, 4]
    assert len(written) == 4   # rgb, depth, mask, mask_visib


def test_a_frame_needs_its_target_and_meshes_for_the_others(tmp_path):
    writer = SceneWriter(tmp_path / "train", ".png", lambda path, a: None, set())
    data = frame_data()
    with pytest.raises(SpmError, match="a frame needs its target object"):
        writer.add_frame(data, 0, [])
    with pytest.raises(SpmError, match="object 1 .obj_id 9. of a frame has no mesh; only a target may lack one"):
        writer.add_frame(data, 0, [(3, None, np.eye(3), np.zeros(3)), (9, None, np.eye(3), np.zeros(3))])


# --------------------------------------------------------------------------- merged folders: each frame's own occlusion

MERGED_FIELDS = ["depth", "mask", "visible_mask", "occlusion_fraction", "occlusion_rects", "distractor_mesh"]


@pytest.fixture(scope="module")
def kinds(tmp_path_factory):
    """Three 64 x 64 folders, 6 frames each: plain (cup), 2-D occluded (box, 20-60 % hidden) and
    cluttered (3-D distractors, randomised K). Read-only for tests."""
    root = tmp_path_factory.mktemp("kinds")
    specs = write_small_specs(root / "specs")
    render_dataset(load_run_specs(["cup"], specs_dir=specs), root / "plain", limit=6)
    render_dataset(load_run_specs(["box"], specs_dir=specs), root / "box", limit=6)
    r = CliRunner().invoke(data_cli, ["occlude", str(root / "box"), "--out", str(root / "occluded"),
                                      "--min", "0.2", "--max", "0.6", "--copies", "1", "--seed", "5"])
    assert r.exit_code == 0, r.output
    (root / "cspecs").mkdir()
    small = CLUTTERED.format(cls="c").replace("[render]", "[image]\nwidth = 64\nheight = 64\n[render]")
    (root / "cspecs" / "c.toml").write_text(small)
    render_dataset(load_run_specs(all_classes=True, specs_dir=root / "cspecs"), root / "cluttered", limit=6)
    return root


def _frames(folder):
    """Every frame of ``folder`` in the export's order, as read_shard's arrays of one frame."""
    for path in open_folder(folder).shards:
        d = read_shard(path, [f for f in MERGED_FIELDS if f in shard_layout(path)])   # a shard of 8 frames may have
        d.setdefault("visible_mask", d["mask"])                                 # no cluttered or occluded one
        for i in range(len(d["mask"])):
            yield {f: d[f][i] for f in d}


def _check_export(folder, bop):
    ids, names = frame_ids(folder), load_objects(bop)
    expected = {}
    for k, frame in enumerate(_frames(folder)):
        scene, im = int(ids.scene_id[k]), int(ids.im_id[k])
        sdir = bop / "train" / f"{scene:06d}"
        info = json.loads((sdir / "scene_gt_info.json").read_text())[str(im)][0]
        scale = json.loads((sdir / "scene_camera.json").read_text())[str(im)]["depth_scale"]
        mask, visible = frame["mask"] > 0, frame["visible_mask"] > 0
        assert info["px_count_all"] == mask.sum() and info["px_count_visib"] == visible.sum()
        assert info["visib_fract"] == pytest.approx(1.0 - float(frame["occlusion_fraction"]), abs=1e-6)
        visib_png = cv2.imread(str(sdir / "mask_visib" / f"{im:06d}_000000.png"), cv2.IMREAD_UNCHANGED) > 0
        np.testing.assert_array_equal(visib_png, visible)
        coco = load_scene_gt_coco(sdir / "scene_gt_coco.json")
        ann = next(a for a in coco["annotations"] if a["image_id"] == im and a["category_id"] == ids.obj_id[k])
        assert ann["area"] == visible.sum()
        np.testing.assert_array_equal(rle_to_mask(ann["segmentation"]), visible)
        depth = cv2.imread(str(sdir / "depth" / f"{im:06d}.png"), cv2.IMREAD_UNCHANGED) * scale / 1000
        hidden_2d = mask & ~visible if frame["occlusion_rects"].any() else np.zeros_like(mask)
        # The stand-in occluder: in front of the target exactly where a rectangle hides it.
        assert (depth[hidden_2d] < frame["depth"][hidden_2d] - 0.015).all()
        np.testing.assert_allclose(depth[~hidden_2d], frame["depth"][~hidden_2d], atol=scale / 1000)
        entry = names[int(ids.obj_id[k])]
        expected[(entry["class"], entry["instance"], im)] = float(frame["occlusion_fraction"])
    return expected


def test_every_merge_order_exports_each_frames_own_occlusion(kinds, tmp_path):
    folders = [kinds / "plain", kinds / "occluded", kinds / "cluttered"]
    kinds_seen = set()
    for n, order in enumerate(itertools.permutations(folders)):
        merged, bop = tmp_path / f"m{n}", tmp_path / f"bop{n}"
        merge_folders(list(order), merged, frames_per_shard=8)
        export_bop(merged, bop)
        expected = _check_export(merged, bop)
        assert len(expected) == 18
        kinds_seen |= {round(f, 6) > 0 for f in expected.values()}
        if n == 0:   # and `import bop` of the export brings each frame's occlusion back
            import_bop(bop, tmp_path / "back", split="train")
            back = {}
            for path in open_folder(tmp_path / "back").shards:
                d = read_shard(path, ["class_name", "instance_name", "path_index", "occlusion_fraction"])
                for cls, name, im, fraction in zip(*d.values()):
                    if cls != "distractor":
                        back[(str(cls), str(name), int(im))] = float(fraction)
            assert back.keys() == expected.keys()
            for key, fraction in expected.items():
                assert back[key] == pytest.approx(fraction, abs=1e-6), key
    assert kinds_seen == {True, False}


def test_camera_json_is_the_specs_camera_and_distractor_names_say_their_size(kinds, tmp_path):
    export_bop(kinds / "cluttered", tmp_path / "bop")
    camera = json.loads((tmp_path / "bop" / "camera.json").read_text())
    K = K_to_corner_origin(intrinsics_from_fov(35.0, 64, 64))   # the spec's, not frame 0's randomised K
    assert [camera[k] for k in ("fx", "fy", "cx", "cy")] == [K[0, 0], K[1, 1], K[0, 2], K[1, 2]]
    frame0 = read_shard(open_folder(kinds / "cluttered").shards[0], ["K"], frames=slice(0, 1))["K"][0]
    assert not np.allclose(frame0, intrinsics_from_fov(35.0, 64, 64))   # the case: frame 0's K was randomised
    objects = load_objects(tmp_path / "bop")
    distractors = [e for e in objects.values() if e.get("role") == "distractor"]
    assert len(distractors) > 2
    names = [e["instance"] for e in distractors]
    assert len(set(names)) == len(names)
    for e in distractors:   # e.g. box-10000@73.1mm: its size, to the decimals that tell its sizes apart
        label = e["instance"].rsplit("@", 1)[1]
        assert label.endswith("mm") and float(label[:-2]) == pytest.approx(e["scale_m"] * 1000, abs=0.05)


def test_a_scene_file_is_saved_beside_where_it_is_loaded_back_and_a_bad_one_is_one_line(tmp_path):
    table = {"0": [{"obj_id": 1, "cam_R_m2c": [1, 0, 0, 0, 1, 0, 0, 0, 1], "cam_t_m2c": [0, 0, 600.0]}]}
    save_scene_file(tmp_path / "scene_gt.json", table)
    assert load_scene_file(tmp_path / "scene_gt.json") == table
    with pytest.raises(SpmError, match=f"^BOP scene file missing: {tmp_path / 'scene_camera.json'}$"):
        load_scene_file(tmp_path / "scene_camera.json")
    (tmp_path / "scene_gt_info.json").write_text("{not json")
    with pytest.raises(SpmError, match=r"scene_gt_info.json: unreadable JSON \("):
        load_scene_file(tmp_path / "scene_gt_info.json")

"""spm_data.formats.bop_scene on merged folders: every frame's BOP ground truth follows its own
occlusion (2-D rectangles, 3-D distractors or none), whatever order the folders were merged in."""

import itertools
import json

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from cli import data_cli
from spm_data.commands.merge import merge_folders
from spm_data.commands.render_jobs import load_run_specs, render_dataset
from spm_data.core.poses import K_to_corner_origin, intrinsics_from_fov
from spm_data.formats.bop import import_bop
from spm_data.formats.bop_export import export_bop
from spm_data.formats.bop_ids import frame_ids, read_objects
from spm_data.formats.coco import load_scene_gt_coco, rle_to_mask
from spm_data.io.folders import open_folder
from spm_data.io.shards import read_shard, shard_layout
from tests.commands.test_render_frames import CLUTTERED
from tests.helpers import write_small_specs

FIELDS = ["depth", "mask", "visible_mask", "occlusion_fraction", "occlusion_rects", "distractor_mesh"]


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
        d = read_shard(path, [f for f in FIELDS if f in shard_layout(path)])   # a shard of 8 frames may have
        d.setdefault("visible_mask", d["mask"])                                 # no cluttered or occluded one
        for i in range(len(d["mask"])):
            yield {f: d[f][i] for f in d}


def _check_export(folder, bop):
    ids, names = frame_ids(folder), read_objects(bop)
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
    objects = read_objects(tmp_path / "bop")
    distractors = [e for e in objects.values() if e.get("role") == "distractor"]
    assert len(distractors) > 2
    names = [e["instance"] for e in distractors]
    assert len(set(names)) == len(names)
    for e in distractors:   # e.g. box-10000@73.1mm: its size, to the decimals that tell its sizes apart
        label = e["instance"].rsplit("@", 1)[1]
        assert label.endswith("mm") and float(label[:-2]) == pytest.approx(e["scale_m"] * 1000, abs=0.05)

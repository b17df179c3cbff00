"""The scenes of a BOP split, frame by frame, with every object in each frame.

The export's driver (bop/export.py) hands :meth:`SceneWriter.add_frame` a frame and its
objects, ``[(obj_id, mesh or None, R (3, 3), t (3,) metres), ...]``, the target first (its
obj_id names the scene, ``scene_id = obj_id - 1``), then the frame's other objects (its 3-D
distractors). The writer does the rest: ``rgb/`` (JPEG in ``*_pbr`` splits), ``depth/``
(the render's depth, each frame's own 2-D occluders as a flat stand-in: :func:`scene_depth`), per object ``k`` of image
``im``
``mask/{im:06d}_{k:06d}.png`` and ``mask_visib/``, and per scene ``scene_camera.json``,
``scene_gt.json``, ``scene_gt_info.json`` and ``scene_gt_coco.json``.

An object with a mesh gets the ground truth bop_toolkit's scripts compute from the export
(bop_gt.object_gt: calc_gt_info's counts and boxes, calc_gt_masks' masks, visibility from the
exported depth with every object of the frame in it); a target without one (an imported
frame) keeps its image-only ground truth (its shard masks, bop_gt.image_gt).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from spm_data.errors import SpmError
from spm_data.core.occlusion import black_out
from spm_data.core.poses import K_to_corner_origin
from spm_data.formats.bop.gt import (depth_scale_for, depth_units, depth_with_occluders, image_gt, object_gt,
                                     png_depth_mm)
from spm_data.formats.bop.models import ply_vertices
from spm_data.formats.coco import FILE_NAME as COCO_FILE
from spm_data.formats.coco import save_scene_gt_coco, scene_coco

SCENE_FILES = {"camera": "scene_camera.json", "gt": "scene_gt.json", "info": "scene_gt_info.json"}


def scene_depth(data: dict, i: int, mask: np.ndarray, visible: np.ndarray) -> np.ndarray:
    """Frame ``i``'s depth (H, W) metres as the export writes it: the render's, with a flat stand-in
    (bop_gt.depth_with_occluders) where the frame's own 2-D occluders hide the target. Decided per
    frame, as a merged shard mixes frames: one with 3-D distractors has them in its rendered depth
    already, so only its pixels inside its occlusion rectangles (if any) get the stand-in; a frame
    without them gets it wherever the target is hidden (occlude's rectangles, an import's mask)."""
    depth = data["depth"][i]
    placed = "distractor_mesh" in data and bool((np.asarray(data["distractor_mesh"][i]) >= 0).any())
    if not placed:
        return depth_with_occluders(depth, mask, visible)
    rects = np.asarray(data["occlusion_rects"][i]) if "occlusion_rects" in data else np.zeros((0, 4), int)
    if not rects.any():
        return depth
    outside = np.ones(mask.shape, bool)
    black_out(outside, rects=rects)
    return depth_with_occluders(depth, mask, visible | outside)


class SceneWriter:
    """The scenes of one split, under ``split_dir`` (EXPORT/SPLIT): ``rgb_suffix`` (".jpg" or
    ".png") and ``encode(path, array)`` write images; ``scales`` (a set) collects every depth
    scale used (camera.json's is the largest)."""

    def __init__(self, split_dir: Path, rgb_suffix: str, encode, scales: set):
        self.split_dir, self.rgb_suffix, self.encode, self.scales = Path(split_dir), rgb_suffix, encode, scales
        self.scenes: dict[int, dict] = {}   # target obj_id -> {"camera", "gt", "info": {im: ...}, "coco": [...]}
        self.split = self.split_dir.name
        self._vertices: dict[int, tuple] = {}   # id(mesh) -> (mesh, its PLY's float32 vertices in mm)

    def add_frame(self, data: dict, i: int, objects) -> None:
        """Frame ``i`` of ``data`` (read_shard's arrays) as the next image of its target's scene,
        with ``objects`` (the module's docstring) as its ground truth, in that order."""
        if not objects:
            raise SpmError("a frame needs its target object; got an empty object list")
        target = int(objects[0][0])
        scene = self.scenes.setdefault(target, {"camera": {}, "gt": {}, "info": {}, "coco": []})
        im = len(scene["gt"])
        sdir = self.split_dir / f"{target - 1:06d}"
        if im == 0:
            for sub in ("rgb", "depth", "mask", "mask_visib"):
                (sdir / sub).mkdir(parents=True)
        mask = data["mask"][i] > 0
        visible = data["visible_mask"][i] > 0 if "visible_mask" in data else mask
        rgb_name = f"rgb/{im:06d}{self.rgb_suffix}"
        self.encode(sdir / rgb_name, data["rgb"][i])
        depth = scene_depth(data, i, mask, visible)
        scale = depth_scale_for(depth)
        self.scales.add(scale)
        units = depth_units(depth, scale)
        self.encode(sdir / "depth" / f"{im:06d}.png", units)
        K = K_to_corner_origin(data["K"][i])
        scene_mm = png_depth_mm(units, scale)   # the depth as BOP's tools read it back
        gts, infos, coco = [], [], []
        for k, (obj_id, mesh, R, t) in enumerate(objects):
            R, t_mm = np.asarray(R, dtype=np.float64), np.asarray(t, dtype=np.float64) * 1000.0   # as scene_gt.json
            if mesh is None:
                if k:
                    raise SpmError(f"object {k} (obj_id {obj_id}) of a frame has no mesh; only a target may "
                                   "lack one (its ground truth is then its image masks)")
                full, seen, info = mask, visible, image_gt(mask, visible, depth)
            else:
                info, full, seen = object_gt(self._ply_vertices(mesh), mesh.faces, K, R, t_mm, scene_mm)
            self.encode(sdir / "mask" / f"{im:06d}_{k:06d}.png", full.astype(np.uint8) * 255)
            self.encode(sdir / "mask_visib" / f"{im:06d}_{k:06d}.png", seen.astype(np.uint8) * 255)
            gts.append({"cam_R_m2c": R.ravel().tolist(), "cam_t_m2c": t_mm.tolist(), "obj_id": int(obj_id)})
            infos.append(info)
            # Masks kept a bit a pixel until the scene's COCO file is written.
            coco.append((int(obj_id), np.packbits(full), np.packbits(seen), info["visib_fract"]))
        # The world is the target's frame (one target a scene): w2c = the target's m2c.
        scene["camera"][str(im)] = {"cam_K": K.ravel().tolist(), "cam_R_w2c": gts[0]["cam_R_m2c"],
                                    "cam_t_w2c": gts[0]["cam_t_m2c"], "depth_scale": scale}
        scene["gt"][str(im)], scene["info"][str(im)] = gts, infos
        scene["coco"].append((im, rgb_name, mask.shape, coco))

    def _ply_vertices(self, mesh) -> np.ndarray:
        # A model is drawn in many frames: its float32 vertices are made once.
        if id(mesh) not in self._vertices:
            self._vertices[id(mesh)] = (mesh, ply_vertices(mesh))   # the mesh kept: its id stays its own
        return self._vertices[id(mesh)][1]

    @staticmethod
    def _coco_frames(entries):
        for im, name, (h, w), objects in entries:
            unpack = lambda bits: np.unpackbits(bits, count=h * w).reshape(h, w)  # noqa: E731
            yield {"im_id": im, "file_name": name, "width": w, "height": h,
                   "objects": [{"obj_id": obj_id, "mask": unpack(full), "mask_visib": unpack(seen),
                                "visib_fract": fract} for obj_id, full, seen, fract in objects]}

    def finish(self, every_id) -> None:
        """Write every scene's JSON files; ``every_id``: the dataset's obj_ids (COCO lists them all
        as categories, as bop_toolkit does)."""
        for target, scene in self.scenes.items():
            sdir = self.split_dir / f"{target - 1:06d}"
            for key, name in SCENE_FILES.items():
                save_scene_file(sdir / name, scene[key])
            coco = scene_coco(self._coco_frames(scene.pop("coco")), dataset="spm", split=self.split,
                              obj_ids=sorted(every_id), bbox_type="amodal")
            save_scene_gt_coco(sdir / COCO_FILE, coco)


def save_scene_file(path: Path, table: dict) -> None:
    """One of a scene's SCENE_FILES (image id -> its entries), as bop_toolkit's inout writes them."""
    path.write_text(json.dumps(table, indent=1))


def load_scene_file(path: Path):
    """One of a scene's SCENE_FILES as written (the importer, read.py, checks what it holds);
    SpmError naming the file when it is missing or not JSON."""
    try:
        with open(path) as fh:
            return json.load(fh)
    except FileNotFoundError:
        raise SpmError(f"BOP scene file missing: {path}") from None
    except (OSError, ValueError) as exc:
        raise SpmError(f"{path}: unreadable JSON ({exc})") from None

"""BOP-format datasets (Hodaň et al.) in and out.

In: ``PATH/SPLIT/SCENE/`` with ``scene_camera.json`` (``cam_K``, ``depth_scale``),
``scene_gt.json`` (``cam_R_m2c``, ``cam_t_m2c`` in mm, ``obj_id``), ``rgb/``,
``depth/`` (uint16 x depth_scale = mm), ``mask/``, ``mask_visib/``: one frame
per (image, object), the full image or a crop around the object.

Out: one scene per object instance, ``camera.json``, ``models/`` and
``models_eval/`` (bop_models.py, for rendered meshes), ``scene_gt_info.json``
with ``visib_fract`` from our occlusions, ``scene_gt_coco.json``; rgb as JPEG in
``*_pbr`` splits, PNG otherwise; written to ``OUT.partial`` and renamed.

K: BOP counts the principal point from the pixel corner (cx = W / 2 for a
centred camera), our shards from the first pixel's centre (OpenCV): export adds
0.5 to cx and cy, import subtracts it (poses.K_to_corner_origin).
"""

from __future__ import annotations

import json
import os
import re
import shutil
from pathlib import Path

import numpy as np

from spm_data.formats.bop_models import save_bop_model, save_models_info
from spm_data.formats.coco import FILE_NAME as COCO_FILE
from spm_data.formats.coco import save_scene_gt_coco, scene_coco
from spm_data.errors import SpmError
from spm_data.io.folders import open_folder
from spm_data.formats.importing import FrameRecord, import_records, pose_problem
from spm_data.core.instances import shard_mesh
from spm_data.io.outputs import check_creatable, space_fix, top_created
from spm_data.core.poses import K_from_corner_origin, K_to_corner_origin
from spm_data.io.shards import read_attrs, read_shard

DEPTH_SCALE = 0.1  # mm per depth unit in exported depth PNGs (BOP's usual choice)


def _load_json(path: Path):
    try:
        with open(path) as fh:
            return json.load(fh)
    except FileNotFoundError:
        raise SpmError(f"BOP scene file missing: {path}") from None
    except (OSError, ValueError) as exc:
        raise SpmError(f"{path}: unreadable JSON ({exc})") from None


def _find(folder: Path, stem: str):
    for suffix in (".png", ".jpg", ".jpeg", ".tif"):
        if (folder / f"{stem}{suffix}").is_file():
            return folder / f"{stem}{suffix}"
    return None


def _numbers(entry, key, n, where) -> np.ndarray:
    """``entry[key]`` as n finite floats; SpmError naming the file, image and object otherwise."""
    value = entry.get(key) if isinstance(entry, dict) else None
    if value is None:
        raise SpmError(f"{where}: no {key!r}; expected {n} numbers, fix the file")
    try:
        arr = np.asarray(value, dtype=np.float64).ravel()
    except (TypeError, ValueError):
        raise SpmError(f"{where}: {key} is not a list of {n} numbers ({str(value)[:60]}); fix the file") from None
    if arr.size != n:
        raise SpmError(f"{where}: {key} has {arr.size} values, expected {n}; fix the file")
    if not np.isfinite(arr).all():
        raise SpmError(f"{where}: {key} has a non-finite value ([{', '.join(f'{v:g}' for v in arr)}]); "
                       f"expected {n} finite numbers, fix the file")
    return arr


def _scene_entries(scene: Path):
    """[(image id, image key, camera entry or None, [(object index, obj_id, R, t m)])] of one scene,
    every pose and camera checked (SpmError naming the file, image and object) before any is imported."""
    cams, gts = _load_json(scene / "scene_camera.json"), _load_json(scene / "scene_gt.json")
    for name, table in (("scene_gt.json", gts), ("scene_camera.json", cams)):
        if not isinstance(table, dict):
            raise SpmError(f"{scene / name}: expected an object of image ids, got {type(table).__name__}")
        bad = [k for k in table if not str(k).isdigit()]
        if bad:
            raise SpmError(f"{scene / name}: image id {bad[0]!r} is not a number; fix the file")
    entries = []
    for im_key in sorted(gts, key=int):
        cam = cams.get(im_key)
        if isinstance(cam, dict) and "cam_K" in cam:
            where = f"{scene / 'scene_camera.json'}: image {im_key}"
            K = _numbers(cam, "cam_K", 9, where)
            if not (K[0] > 0 and K[4] > 0):
                raise SpmError(f"{where}: cam_K has fx = {K[0]:g}, fy = {K[4]:g}; expected fx, fy > 0, fix the file")
            if "depth_scale" in cam and not _numbers(cam, "depth_scale", 1, where)[0] > 0:
                raise SpmError(f"{where}: depth_scale is {cam['depth_scale']}; expected > 0, fix the file")
        if not isinstance(gts[im_key], list):
            raise SpmError(f"{scene / 'scene_gt.json'}: image {im_key}: expected a list of objects; fix the file")
        objects = []
        for g, gt in enumerate(gts[im_key]):
            where = f"{scene / 'scene_gt.json'}: image {im_key}, object {g}"
            obj = _numbers(gt, "obj_id", 1, where)[0]
            if obj != int(obj):
                raise SpmError(f"{where}: obj_id is {obj:g}; expected a whole number, fix the file")
            R = _numbers(gt, "cam_R_m2c", 9, where).reshape(3, 3)
            t = _numbers(gt, "cam_t_m2c", 3, where) / 1000.0
            problem = pose_problem(R, t)
            if problem is not None:
                raise SpmError(f"{where}: {problem}; fix the file")
            objects.append((g, int(obj), R, t))
        entries.append((int(im_key), im_key, cam if isinstance(cam, dict) else None, objects))
    return entries


def bop_records(path, split="train_pbr", crop=False, classes=None):
    """(records, problems) for every (image, object) of a BOP split. Every scene's poses
    and cameras are checked first: SpmError naming the file, image and object."""
    root = Path(path) / split
    scenes = sorted(p for p in root.iterdir() if p.is_dir()) if root.is_dir() else []
    if not scenes:
        raise SpmError(f"{root}: no BOP scenes (folders with scene_gt.json)")
    checked = [(scene, _scene_entries(scene)) for scene in scenes]
    records, problems = [], []
    for scene, entries in checked:
        for im, im_key, cam, objects in entries:
            rgb = _find(scene / "rgb", f"{im:06d}") or _find(scene / "gray", f"{im:06d}")
            if rgb is None:
                problems.append((f"{scene.name}/rgb/{im:06d}", "missing image"))
                continue
            if cam is None or "cam_K" not in cam:
                problems.append((str(rgb), "no cam_K in scene_camera.json"))
                continue
            depth = _find(scene / "depth", f"{im:06d}")
            for g, obj, R, t in objects:
                mask = _find(scene / "mask", f"{im:06d}_{g:06d}")
                visib = _find(scene / "mask_visib", f"{im:06d}_{g:06d}")
                records.append(FrameRecord(
                    image=str(rgb), class_name=(classes or {}).get(obj, f"bop-obj{obj}"),
                    instance_name=f"bop-obj{obj}", instance_id=obj, R=tuple(R.ravel()), t=tuple(t),
                    K=tuple(K_from_corner_origin(cam["cam_K"]).ravel()), mask=str(mask) if mask else None,
                    visible_mask=str(visib) if visib else None, depth=str(depth) if depth else None,
                    depth_scale_m=float(cam.get("depth_scale", 1.0)) / 1000.0, path_index=im,
                    distance=float(np.linalg.norm(t)), crop="mask" if crop else None))
    return records, problems


def import_bop(path, out_dir, *, split="train_pbr", crop=None, classes_csv=None, frames_per_shard=256,
               progress=None, executor=None):
    """Import a BOP split; ``crop``: output size in pixels of square crops around each object, or None."""
    from spm_data.formats.coil100 import read_class_map

    classes = read_class_map(classes_csv) if classes_csv else None
    records, problems = bop_records(path, split, crop=bool(crop), classes=classes)
    summary = import_records(records, out_dir, source="bop", prefix=f"bop-{split}",
                             size=(crop, crop) if crop else None, frames_per_shard=frames_per_shard,
                             attrs={"import": "bop", "split": split}, progress=progress, executor=executor)
    return summary, problems


# --------------------------------------------------------------------------- export

SPLIT_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_-]*")  # one folder inside the dataset, never a path
RGB_SUFFIX = {True: ".jpg", False: ".png"}  # keyed by "a PBR split": BOP stores PBR renders as JPEG
JPEG_QUALITY = 95  # BlenderProc's BOP writer's setting
# An occluder's depth, as a fraction of the object's nearest point: far enough in front (20 %,
# 100 mm at 0.5 m) that bop_toolkit's visibility test (15 mm tolerance) sees the object hidden.
OCCLUDER_DEPTH = 0.8


def _encode(path: Path, array: np.ndarray) -> None:
    import cv2

    img = cv2.cvtColor(array, cv2.COLOR_RGB2BGR) if array.ndim == 3 else array
    params = [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY] if path.suffix == ".jpg" else []
    ok, data = cv2.imencode(path.suffix, img, params)
    if not ok:
        raise SpmError(f"could not encode {path}")
    path.write_bytes(data.tobytes())  # an OSError (disk full, read-only) names its errno, unlike cv2.imwrite


def _bbox(mask: np.ndarray) -> list[int]:
    """[x, y, w, h] as bop_toolkit's calc_gt_info writes it: w = x_max - x_min (no + 1; COCO's
    boxes in scene_gt_coco.json do add 1), [-1, -1, -1, -1] when empty."""
    ys, xs = np.nonzero(mask)
    if len(ys) == 0:
        return [-1, -1, -1, -1]
    return [int(xs.min()), int(ys.min()), int(xs.max() - xs.min()), int(ys.max() - ys.min())]


def _depth_with_occluders(depth: np.ndarray, mask: np.ndarray, visible: np.ndarray) -> np.ndarray:
    """Depth (H, W) metres where our 2-D occluders hide the object: there, a flat occluder at
    OCCLUDER_DEPTH of the object's nearest depth. BOP's tools (calc_gt_info, VSD) find what is
    visible from depth, so without it they would call every occluded object fully visible."""
    hidden = mask & ~visible
    if not hidden.any():
        return depth
    out = depth.copy()
    out[hidden] = OCCLUDER_DEPTH * depth[mask & (depth > 0)].min()
    return out


def _check_out(out_dir: Path) -> None:
    if out_dir.exists() and not out_dir.is_dir():
        raise SpmError(f"{out_dir} is a file; give --out a new folder to export into")
    if out_dir.exists() and any(out_dir.iterdir()):
        raise SpmError(f"{out_dir} exists and is not empty; export into a new folder")
    check_creatable(out_dir, "create", "give --out a new folder to export into",
                    "give --out a folder in a writable place")


class _Export:
    """The BOP dataset being written into ``root`` (OUT.partial): one scene per object."""

    def __init__(self, root: Path, split: str, meshes_from=None):
        self.root, self.split, self.meshes_from = root, split, meshes_from
        self.rgb_suffix = RGB_SUFFIX[split.endswith("_pbr")]
        self.objects: dict[tuple, int] = {}
        self.scenes: dict[int, dict] = {}
        self.models_info, self.no_model, self.frames = {}, set(), 0
        for sub in ("models", "models_eval"):
            (root / sub).mkdir(parents=True)

    def object_id(self, key: tuple, attrs: dict, instance_id: int) -> int:
        if key not in self.objects:
            self.objects[key] = obj_id = len(self.objects) + 1
            mesh = shard_mesh(attrs, instance_id, spec_dir=self.meshes_from)
            if mesh is None:
                self.no_model.add(key)
            else:
                self.models_info[obj_id] = save_bop_model(self.root, obj_id, mesh)
        return self.objects[key]

    def add_frame(self, data: dict, i: int, obj_id: int) -> None:
        scene = self.scenes.setdefault(obj_id, {"camera": {}, "gt": {}, "info": {}, "coco": []})
        im = len(scene["gt"])
        sdir = self.root / self.split / f"{obj_id - 1:06d}"
        if im == 0:
            for sub in ("rgb", "depth", "mask", "mask_visib"):
                (sdir / sub).mkdir(parents=True)
        mask = data["mask"][i] > 0
        visible = data["visible_mask"][i] > 0 if "visible_mask" in data else mask
        rgb_name = f"rgb/{im:06d}{self.rgb_suffix}"
        _encode(sdir / rgb_name, data["rgb"][i])
        # Rendered distractors are in the depth already; only 2-D rectangles need a stand-in.
        depth = data["depth"][i] if "distractor_mesh" in data else _depth_with_occluders(data["depth"][i], mask, visible)
        depth_units = np.round(depth.astype(np.float64) * 1000.0 / DEPTH_SCALE)
        _encode(sdir / "depth" / f"{im:06d}.png", np.clip(depth_units, 0, 65535).astype(np.uint16))
        _encode(sdir / "mask" / f"{im:06d}_000000.png", mask.astype(np.uint8) * 255)
        _encode(sdir / "mask_visib" / f"{im:06d}_000000.png", visible.astype(np.uint8) * 255)
        scene["camera"][str(im)] = {"cam_K": K_to_corner_origin(data["K"][i]).ravel().tolist(),
                                    "depth_scale": DEPTH_SCALE}
        scene["gt"][str(im)] = [{"cam_R_m2c": data["R"][i].ravel().tolist(),
                                 "cam_t_m2c": (data["t"][i] * 1000.0).tolist(), "obj_id": obj_id}]
        full, vis = int(mask.sum()), int(visible.sum())
        fract = vis / full if full else 0.0
        box = _bbox(mask) if vis else [-1, -1, -1, -1]  # as calc_gt_info: no box for an unseen object
        scene["info"][str(im)] = [{"bbox_obj": box, "bbox_visib": _bbox(visible),
                                   "px_count_all": full, "px_count_valid": int((depth[mask] > 0).sum()),
                                   "px_count_visib": vis, "visib_fract": fract}]
        # Masks kept a bit a pixel until the scene's COCO file is written.
        scene["coco"].append((im, rgb_name, mask.shape, np.packbits(mask), np.packbits(visible), fract))
        self.frames += 1

    def _coco_frames(self, entries, obj_id):
        for im, name, (h, w), mask, visible, fract in entries:
            unpack = lambda bits: np.unpackbits(bits, count=h * w).reshape(h, w)  # noqa: E731
            yield {"im_id": im, "file_name": name, "width": w, "height": h,
                   "objects": [{"obj_id": obj_id, "mask": unpack(mask), "mask_visib": unpack(visible),
                                "visib_fract": fract}]}

    def finish(self, first_shard) -> None:
        for obj_id, scene in self.scenes.items():
            sdir = self.root / self.split / f"{obj_id - 1:06d}"
            for name in ("camera", "gt", "info"):
                key = {"camera": "scene_camera", "gt": "scene_gt", "info": "scene_gt_info"}[name]
                (sdir / f"{key}.json").write_text(json.dumps(scene[name], indent=1))
            coco = scene_coco(self._coco_frames(scene.pop("coco"), obj_id), dataset="spm", split=self.split,
                              obj_ids=[obj_id], bbox_type="amodal")
            save_scene_gt_coco(sdir / COCO_FILE, coco)
        first = read_shard(first_shard, ["K", "rgb"], frames=slice(0, 1))
        K, (h, w) = K_to_corner_origin(first["K"][0]), first["rgb"].shape[1:3]
        (self.root / "camera.json").write_text(json.dumps({"cx": K[0, 2], "cy": K[1, 2], "fx": K[0, 0],
                                                           "fy": K[1, 1], "width": int(w), "height": int(h),
                                                           "depth_scale": DEPTH_SCALE}))
        save_models_info(self.root / "models" / "models_info.json", self.models_info)
        save_models_info(self.root / "models_eval" / "models_info.json", self.models_info)


def export_bop(in_dir, out_dir, *, split="train", progress=None, allow_partial=False, meshes_from=None) -> dict:
    """Write the shards of ``in_dir`` as a BOP dataset at ``out_dir``. Returns counts.
    split: one folder name (BOP's: train, train_pbr, val, test...). meshes_from: the folder
    a mesh-file spec's paths start from, when not the spec folder its shards recorded
    (spm_data.core.instances.shard_mesh)."""
    out_dir = Path(out_dir)
    if not SPLIT_NAME.fullmatch(str(split)):
        raise SpmError(f"--split {split!r}: expected one folder name of letters, digits, '_' or '-' "
                       "(BOP's are train, train_pbr, val, test)")
    if meshes_from is not None and not Path(meshes_from).is_dir():
        raise SpmError(f"--meshes-from {meshes_from}: no such folder; give the folder the spec file is in")
    _check_out(out_dir)
    # Every shard read below is verified as it is read; the export is built in OUT.partial, so a
    # corrupt shard (or a full disk) leaves nothing behind.
    shards = open_folder(in_dir, allow_partial=allow_partial).shards
    tmp = out_dir.with_name(out_dir.name + ".partial")
    shutil.rmtree(tmp, ignore_errors=True)
    made = top_created(tmp / "models")  # what this export creates: removed on failure
    try:
        export = _Export(tmp, split, meshes_from)
        for path in shards:
            attrs, data = read_attrs(path), read_shard(path)
            for i in range(len(data["pose"])):
                key = (str(data["class_name"][i]), str(data["instance_name"][i]))
                export.add_frame(data, i, export.object_id(key, attrs, int(data["instance_id"][i])))
                if progress:
                    progress(1)
        export.finish(shards[0])
        if out_dir.exists():
            out_dir.rmdir()
        os.replace(tmp, out_dir)
    except BaseException as exc:
        shutil.rmtree(made, ignore_errors=True)
        if isinstance(exc, OSError):
            fix = space_fix(exc, "give --out a folder in a writable place")
            raise SpmError(f"could not export to {out_dir}: {exc.strerror or exc}; nothing was written; "
                           f"{fix}") from None
        raise
    return {"frames": export.frames, "objects": len(export.objects), "scenes": len(export.scenes),
            "without_model": sorted(f"{c}/{n}" for c, n in export.no_model)}

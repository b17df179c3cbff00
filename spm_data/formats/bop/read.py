"""BOP-format datasets (Hodaň et al.) in; out is bop/export.py.

In: ``PATH/SPLIT/SCENE/`` with ``scene_camera.json`` (``cam_K``, ``depth_scale``),
``scene_gt.json`` (``cam_R_m2c``, ``cam_t_m2c`` in mm, ``obj_id``), ``rgb/``,
``depth/`` (uint16 x depth_scale = mm), ``mask/``, ``mask_visib/``: one frame
per (image, object), the full image or a crop around the object. An
``objects.json`` beside the splits (our export writes one) gives each obj_id its
class and instance names back.

K: BOP counts the principal point from the pixel corner (cx = W / 2 for a
centred camera), our shards from the first pixel's centre (OpenCV): import
subtracts 0.5 from cx and cy (poses.K_from_corner_origin).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from spm_data.errors import SpmError
from spm_data.core.poses import K_from_corner_origin
from spm_data.formats.bop.ids import OBJECTS_FILE, load_objects
from spm_data.formats.bop.scene import SCENE_FILES, load_scene_file
from spm_data.formats.importing import FrameRecord, import_records, pose_problem


def _find(folder: Path, stem: str):
    for suffix in (".png", ".jpg", ".jpeg", ".tif"):
        if (folder / f"{stem}{suffix}").exists():   # not only a regular file: the read says what else it is
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
    cams, gts = load_scene_file(scene / SCENE_FILES["camera"]), load_scene_file(scene / SCENE_FILES["gt"])
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
    names = load_objects(path) if (Path(path) / OBJECTS_FILE).is_file() else {}
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
                named = names.get(obj, {"class": f"bop-obj{obj}", "instance": f"bop-obj{obj}", "instance_id": obj})
                records.append(FrameRecord(
                    image=str(rgb), class_name=(classes or {}).get(obj, named["class"]),
                    instance_name=named["instance"], instance_id=named["instance_id"], R=tuple(R.ravel()), t=tuple(t),
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

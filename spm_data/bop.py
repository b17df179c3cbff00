"""BOP-format datasets (Hodaň et al.) in and out.

In: ``PATH/SPLIT/SCENE/`` with ``scene_camera.json`` (``cam_K``, ``depth_scale``),
``scene_gt.json`` (``cam_R_m2c``, ``cam_t_m2c`` in mm, ``obj_id``), ``rgb/``,
``depth/`` (uint16 x depth_scale = mm), ``mask/``, ``mask_visib/``: one frame
per (image, object), the full image or a crop around the object.

Out: one scene per object instance, ``camera.json``, ``models/`` (PLY in mm and
``models_info.json``, for rendered meshes), ``scene_gt_info.json`` with
``visib_fract`` from our occlusions; written to ``OUT.partial`` and renamed.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import numpy as np

from spm_data.errors import SpmError
from spm_data.importing import FrameRecord, import_records, pose_problem
from spm_data.folders import open_folder
from spm_data.outputs import space_fix, top_created, unwritable
from spm_data.shards import read_attrs, read_shard

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
                    K=tuple(float(x) for x in cam["cam_K"]), mask=str(mask) if mask else None,
                    visible_mask=str(visib) if visib else None, depth=str(depth) if depth else None,
                    depth_scale_m=float(cam.get("depth_scale", 1.0)) / 1000.0, path_index=im,
                    distance=float(np.linalg.norm(t)), crop="mask" if crop else None))
    return records, problems


def import_bop(path, out_dir, *, split="train_pbr", crop=None, classes_csv=None, frames_per_shard=256,
               workers=1, progress=None, executor=None):
    """Import a BOP split; ``crop``: output size in pixels of square crops around each object, or None."""
    from spm_data.coil100 import read_class_map

    classes = read_class_map(classes_csv) if classes_csv else None
    records, problems = bop_records(path, split, crop=bool(crop), classes=classes)
    summary = import_records(records, out_dir, source="bop", prefix=f"bop-{split}",
                             size=(crop, crop) if crop else None, frames_per_shard=frames_per_shard,
                             attrs={"import": "bop", "split": split}, workers=workers, progress=progress, executor=executor)
    return summary, problems


# --------------------------------------------------------------------------- export

def _png(path: Path, array: np.ndarray) -> None:
    import cv2

    img = cv2.cvtColor(array, cv2.COLOR_RGB2BGR) if array.ndim == 3 else array
    ok, png = cv2.imencode(".png", img)
    if not ok:
        raise SpmError(f"could not encode {path} as PNG")
    path.write_bytes(png.tobytes())  # an OSError (disk full, read-only) names its errno, unlike cv2.imwrite


def _bbox(mask: np.ndarray) -> list[int]:
    ys, xs = np.nonzero(mask)
    if len(ys) == 0:
        return [-1, -1, 0, 0]
    return [int(xs.min()), int(ys.min()), int(xs.max() - xs.min() + 1), int(ys.max() - ys.min() + 1)]


def export_bop(in_dir, out_dir, *, split="train", progress=None, allow_partial=False) -> dict:
    """Write the shards of ``in_dir`` as a BOP dataset at ``out_dir``. Returns counts."""
    import trimesh

    from spm_data.render_jobs import shard_mesh

    out_dir = Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise SpmError(f"{out_dir} is a file; give --out a new folder to export into")
    if out_dir.exists() and any(out_dir.iterdir()):
        raise SpmError(f"{out_dir} exists and is not empty; export into a new folder")
    problem = unwritable(out_dir.parent)
    if problem and problem[1] == "file":
        raise SpmError(f"cannot create {out_dir}: {problem[0]} is a file; give --out a new folder to export into")
    if problem:
        raise SpmError(f"cannot create {out_dir}: {problem[0]} is read-only; give --out a folder in a writable place")
    # Every shard read below is verified as it is read; the export is built in OUT.partial, so a
    # corrupt shard (or a full disk) leaves nothing behind.
    shards = open_folder(in_dir, allow_partial=allow_partial).shards
    tmp = out_dir.with_name(out_dir.name + ".partial")
    shutil.rmtree(tmp, ignore_errors=True)
    made = top_created(tmp / "models")  # what this export creates: removed on failure
    objects: dict[tuple, int] = {}
    scenes: dict[int, dict] = {}
    models_info, no_model, frames = {}, set(), 0
    try:
        (tmp / "models").mkdir(parents=True)
        for path in shards:
            attrs = read_attrs(path)
            data = read_shard(path)
            for i in range(len(data["pose"])):
                key = (str(data["class_name"][i]), str(data["instance_name"][i]))
                if key not in objects:
                    objects[key] = obj_id = len(objects) + 1
                    mesh = shard_mesh(attrs, int(data["instance_id"][i]))
                    if mesh is None:
                        no_model.add(key)
                    else:
                        tm = trimesh.Trimesh(mesh.vertices * 1000.0, mesh.faces, process=True)
                        tm.export(tmp / "models" / f"obj_{obj_id:06d}.ply")
                        lo, hi = tm.bounds
                        hull = tm.convex_hull.vertices
                        diameter = float(np.max(np.linalg.norm(hull[:, None] - hull[None], axis=2)))
                        models_info[str(obj_id)] = {"diameter": diameter, "min_x": lo[0], "min_y": lo[1],
                                                    "min_z": lo[2], "size_x": hi[0] - lo[0],
                                                    "size_y": hi[1] - lo[1], "size_z": hi[2] - lo[2]}
                obj_id = objects[key]
                scene = scenes.setdefault(obj_id, {"camera": {}, "gt": {}, "info": {}})
                im = len(scene["gt"])
                sdir = tmp / split / f"{obj_id - 1:06d}"
                if im == 0:
                    for sub in ("rgb", "depth", "mask", "mask_visib"):
                        (sdir / sub).mkdir(parents=True)
                mask = data["mask"][i]
                visible = data["visible_mask"][i] if "visible_mask" in data else mask
                _png(sdir / "rgb" / f"{im:06d}.png", data["rgb"][i])
                depth_units = np.round(data["depth"][i].astype(np.float64) * 1000.0 / DEPTH_SCALE)
                _png(sdir / "depth" / f"{im:06d}.png", np.clip(depth_units, 0, 65535).astype(np.uint16))
                _png(sdir / "mask" / f"{im:06d}_000000.png", (mask > 0).astype(np.uint8) * 255)
                _png(sdir / "mask_visib" / f"{im:06d}_000000.png", (visible > 0).astype(np.uint8) * 255)
                scene["camera"][str(im)] = {"cam_K": data["K"][i].ravel().tolist(), "depth_scale": DEPTH_SCALE}
                scene["gt"][str(im)] = [{"cam_R_m2c": data["R"][i].ravel().tolist(),
                                         "cam_t_m2c": (data["t"][i] * 1000.0).tolist(), "obj_id": obj_id}]
                full, vis = int((mask > 0).sum()), int((visible > 0).sum())
                scene["info"][str(im)] = [{"bbox_obj": _bbox(mask), "bbox_visib": _bbox(visible),
                                           "px_count_all": full, "px_count_valid": int((data["depth"][i] > 0).sum()),
                                           "px_count_visib": vis, "visib_fract": vis / full if full else 0.0}]
                frames += 1
                if progress:
                    progress(1)
        for obj_id, scene in scenes.items():
            sdir = tmp / split / f"{obj_id - 1:06d}"
            for name, payload in (("scene_camera", scene["camera"]), ("scene_gt", scene["gt"]),
                                  ("scene_gt_info", scene["info"])):
                (sdir / f"{name}.json").write_text(json.dumps(payload, indent=1))
        first = read_shard(shards[0], ["K", "rgb"], frames=slice(0, 1))
        K, (h, w) = first["K"][0], first["rgb"].shape[1:3]
        (tmp / "camera.json").write_text(json.dumps({"cx": K[0, 2], "cy": K[1, 2], "fx": K[0, 0], "fy": K[1, 1],
                                                     "width": int(w), "height": int(h), "depth_scale": DEPTH_SCALE}))
        (tmp / "models" / "models_info.json").write_text(json.dumps(models_info, indent=1))
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
    return {"frames": frames, "objects": len(objects), "scenes": len(scenes),
            "without_model": sorted(f"{c}/{n}" for c, n in no_model)}

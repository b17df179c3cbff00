"""BOP-style COCO ground truth: ``SCENE/scene_gt_coco.json``.

The layout bop_toolkit's ``scripts/calc_gt_coco.py`` and BlenderProc's BOP writer
produce, so COCO tools (pycocotools, detectron2) read our scenes as they read BOP's:
``info``, ``licenses`` (empty), ``categories`` (one per obj_id, ``name`` = str(obj_id),
``supercategory`` = dataset), ``images`` (``id`` = BOP im_id, ``file_name`` relative to
the scene folder) and ``annotations`` whose ``segmentation`` is the *visible* mask as
uncompressed COCO RLE. Numbers are computed here with numpy; pycocotools is not needed.
"""

from __future__ import annotations

import datetime
import json
import os

import numpy as np

from spm_data.errors import SpmError, one_line
from spm_data.io.files import atomic_file

FILE_NAME = "scene_gt_coco.json"
TOP_KEYS = ("info", "licenses", "categories", "images", "annotations")
# bop_toolkit and BlenderProc mark objects less than 10 % visible "ignore": true, kept
# for readers that want it. Stock pycocotools COCOeval overwrites the flag with iscrowd
# and detectron2's load_coco_json refuses ignore=true, so it changes no COCO score.
IGNORE_BELOW_VISIB_FRACT = 0.1
# The format's home and version, as both writers put them in "info".
INFO_URL = "https://github.com/thodan/bop_toolkit"
INFO_VERSION = "0.1.0"


def mask_to_rle(mask) -> dict:
    """(H, W) bool/uint8 mask (nonzero = object) -> uncompressed COCO RLE
    ``{"counts": [int, ...], "size": [H, W]}``: run lengths over the pixels in
    column-major (Fortran) order, alternating background/object and starting with
    background, so a mask whose first pixel is set starts with a 0 run."""
    mask = np.asarray(mask)
    if mask.ndim != 2:
        raise SpmError(f"a mask must be 2-D (H, W), got shape {mask.shape}")
    flat = mask.ravel(order="F") != 0
    if flat.size == 0:
        return {"counts": [], "size": [int(d) for d in mask.shape]}
    # Run boundaries: where the value changes, plus both ends.
    edges = np.concatenate(([0], np.flatnonzero(flat[1:] != flat[:-1]) + 1, [flat.size]))
    counts = np.diff(edges).tolist()
    if flat[0]:
        counts.insert(0, 0)
    return {"counts": counts, "size": [int(d) for d in mask.shape]}


def _rle_problem(rle) -> str | None:
    """Why ``rle`` is not an uncompressed RLE whose runs fill its size, or None."""
    if not isinstance(rle, dict) or "counts" not in rle or "size" not in rle:
        return "segmentation is not an RLE {'counts', 'size'}"
    size, counts = rle["size"], rle["counts"]
    if not (isinstance(size, list) and len(size) == 2
            and all(isinstance(d, int) and not isinstance(d, bool) and d >= 0 for d in size)):
        return f"RLE size {str(size)[:40]} is not [height, width]"
    if isinstance(counts, str):
        return "RLE counts are compressed (a string); expected the list of run lengths BOP writes"
    if not isinstance(counts, list) or not all(isinstance(c, int) and not isinstance(c, bool) and c >= 0
                                                for c in counts):
        return "RLE counts are not a list of non-negative integers"
    if sum(counts) != size[0] * size[1]:
        return f"RLE counts sum to {sum(counts)}, size {size[0]}x{size[1]} needs {size[0] * size[1]}"
    return None


def rle_to_mask(rle) -> np.ndarray:
    """Uncompressed COCO RLE (as ``mask_to_rle`` writes) -> (H, W) bool mask.
    SpmError when the counts do not fill ``size`` exactly."""
    problem = _rle_problem(rle)
    if problem:
        raise SpmError(problem)
    counts = np.asarray(rle["counts"], dtype=np.int64)
    values = np.arange(counts.size) % 2 == 1  # odd runs are object
    return np.repeat(values, counts).reshape(rle["size"], order="F")


def mask_bbox(mask) -> list[int]:
    """(H, W) mask -> ``[x, y, w, h]`` (ints) of the tightest box around its nonzero
    pixels; ``[0, 0, 0, 0]`` for an empty mask, as pycocotools' toBbox gives
    (bop_toolkit's version fails on one; its callers skip empty masks first)."""
    mask = np.asarray(mask) != 0
    rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
    if rows.size == 0:
        return [0, 0, 0, 0]
    return [int(cols[0]), int(rows[0]), int(cols[-1] - cols[0] + 1), int(rows[-1] - rows[0] + 1)]


def _annotation(ann_id, image_id, obj, frame, bbox_type) -> dict | None:
    """One object's annotation, or None when its visible (or, for an amodal box, full)
    mask is empty: both writers leave such objects out."""
    visible = np.asarray(obj["mask_visib"]) != 0
    box_mask = visible if bbox_type == "modal" else np.asarray(obj["mask"]) != 0
    for mask in (visible, box_mask):
        if mask.shape != (frame["height"], frame["width"]):
            raise SpmError(f"image {image_id} ({frame['file_name']}): object {obj['obj_id']}'s mask has shape "
                           f"{mask.shape}, the image (height, width) = ({frame['height']}, {frame['width']})")
    if not visible.any() or not box_mask.any():
        return None
    return {"id": ann_id, "image_id": image_id, "category_id": int(obj["obj_id"]), "iscrowd": 0,
            "area": int(visible.sum()), "bbox": mask_bbox(box_mask), "segmentation": mask_to_rle(visible),
            "width": int(visible.shape[1]), "height": int(visible.shape[0]),
            "ignore": bool(obj["visib_fract"] < IGNORE_BELOW_VISIB_FRACT)}


def creation_time() -> datetime.datetime:
    """The date an export records: ``SOURCE_DATE_EPOCH`` (seconds since 1970, UTC; the
    reproducible-builds convention) when set, so two exports of one folder are byte-identical;
    else now. SpmError for a value that is not a whole number of seconds."""
    text = os.environ.get("SOURCE_DATE_EPOCH", "").strip()
    if not text:
        return datetime.datetime.now(datetime.timezone.utc)
    if not text.isdigit() or int(text) > 253402300799:   # 9999-12-31: the last date isoformat can write
        raise SpmError(f"SOURCE_DATE_EPOCH={text!r}: expected whole seconds since 1970-01-01 UTC (e.g. "
                       "$(git log -1 --format=%ct)), or unset it")
    return datetime.datetime.fromtimestamp(int(text), datetime.timezone.utc)


def scene_coco(frames, *, dataset: str, split: str = "train", obj_ids=None, bbox_type: str = "modal",
               created: datetime.datetime | None = None) -> dict:
    """One scene's COCO ground truth (the dict ``save_scene_gt_coco`` writes).

    ``frames``: one dict per image, ``{"im_id": int (default: its index), "file_name":
    "rgb/000000.jpg" (relative to the scene folder), "width": W, "height": H, "objects":
    [{"obj_id": int, "mask_visib": (H, W) bool/uint8, "visib_fract": float, "mask": (H, W)
    full mask, only for bbox_type="amodal"}, ...]}``. ``obj_ids``: the categories to list
    (bop_toolkit lists every model of the dataset); default, the obj_ids that occur.
    ``bbox_type``: "modal" boxes the visible mask; "amodal" the full mask, which is what
    bop_toolkit and BlenderProc put in scene_gt_coco.json by default. Annotation ids run
    from 1 over the scene; ``created`` (UTC datetime, default :func:`creation_time`) fills the dates."""
    if bbox_type not in ("modal", "amodal"):
        raise SpmError(f"bbox_type must be 'modal' or 'amodal', not {bbox_type!r}")
    frames = list(frames)  # walked twice: images, then the default categories
    stamp = created if created is not None else creation_time()
    when = stamp.isoformat(" ")
    images, annotations = [], []
    for index, frame in enumerate(frames):
        image_id = int(frame.get("im_id", index))
        images.append({"id": image_id, "file_name": str(frame["file_name"]), "width": int(frame["width"]),
                       "height": int(frame["height"]), "date_captured": when, "license": 1,
                       "coco_url": "", "flickr_url": ""})
        for obj in frame["objects"]:
            ann = _annotation(len(annotations) + 1, image_id, obj, frame, bbox_type)
            if ann is not None:
                annotations.append(ann)
    if obj_ids is None:
        obj_ids = {int(obj["obj_id"]) for frame in frames for obj in frame["objects"]}
    return {"info": {"description": f"{dataset}_{split}", "url": INFO_URL, "version": INFO_VERSION,
                     "year": stamp.year, "contributor": "", "date_created": when},
            "licenses": [],
            "categories": [{"id": int(i), "name": str(int(i)), "supercategory": dataset} for i in sorted(obj_ids)],
            "images": images, "annotations": annotations}


def save_scene_gt_coco(path, payload: dict) -> None:
    """Write ``payload`` (``scene_coco``'s dict) to ``path`` atomically: the old file or
    the whole new one, never half. One top-level key a line, values compact, as
    bop_toolkit's save_json lays it out: indenting would put every RLE run on its own line."""
    lines = [f'  "{key}": {json.dumps(payload[key], sort_keys=True)}' for key in sorted(payload)]
    with atomic_file(path) as tmp, open(tmp, "w") as fh:
        fh.write("{\n" + ",\n".join(lines) + "\n}\n")
        fh.flush()
        os.fsync(fh.fileno())


def _payload_problem(payload) -> str | None:
    """The first reason ``payload`` is not a scene COCO file, or None."""
    if not isinstance(payload, dict):
        return "not a JSON object"
    missing = [key for key in TOP_KEYS if not isinstance(payload.get(key), dict if key == "info" else list)]
    if missing:
        return f"missing or mistyped top-level key(s) {', '.join(missing)}"
    sizes = {}
    for image in payload["images"]:
        if not isinstance(image, dict) or not all(isinstance(image.get(k), int) for k in ("id", "width", "height")):
            return f"image entry {str(image)[:60]} lacks an integer id, width or height"
        sizes[image["id"]] = [image["height"], image["width"]]
    for ann in payload["annotations"]:
        where = f"annotation {ann.get('id') if isinstance(ann, dict) else '?'}"
        if not isinstance(ann, dict) or ann.get("image_id") not in sizes:
            return f"{where}: image_id not among the images"
        problem = _rle_problem(ann.get("segmentation"))
        if problem:
            return f"{where}: {problem}"
        if ann["segmentation"]["size"] != sizes[ann["image_id"]]:
            return (f"{where}: RLE size {ann['segmentation']['size']} is not image {ann['image_id']}'s "
                    f"[height, width] {sizes[ann['image_id']]}")
    return None


def load_scene_gt_coco(path) -> dict:
    """Read a ``scene_gt_coco.json`` (ours, bop_toolkit's or BlenderProc's) and check it:
    the top-level keys, and every annotation's RLE fills its image's [height, width].
    A one-line SpmError naming the file otherwise. Masks stay RLE: ``rle_to_mask``."""
    try:
        with open(path) as fh:
            payload = json.load(fh)
    except FileNotFoundError:
        raise SpmError(f"COCO ground truth missing: {path}") from None
    except (OSError, ValueError) as exc:
        raise SpmError(f"{path}: unreadable JSON ({one_line(exc)})") from None
    problem = _payload_problem(payload)
    if problem:
        raise SpmError(f"{path}: {one_line(problem)}; not a scene_gt_coco.json")
    return payload

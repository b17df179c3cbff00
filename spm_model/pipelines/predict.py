"""The library call behind ``spm predict``: poses of image files from a saved model."""

from __future__ import annotations

import json

import numpy as np

from spm_data.errors import ImageError, one_line
from spm_model.errors import FeatureError, ModelError
from spm_data.io.images import decode_bytes, read_image_file
from spm_model.bench.feature_cache import progress_phase
from spm_model.pipelines.evaluate import load_model

LABEL_NAMES = ("rx", "ry", "rz", "tx", "ty", "tz")


def roi_mask(roi, width: int, height: int) -> np.ndarray:
    """(height, width) uint8 mask of the region of interest ``(x, y, w, h)`` (pixels); ModelError
    unless the box lies inside the image and is not empty (never clipped or wrapped)."""
    x, y, w, h = (int(v) for v in roi)
    if x < 0 or y < 0:
        problem = "starts at a negative x or y"
    elif w < 1 or h < 1:
        problem = "is empty (width and height must be at least 1)"
    elif x >= width or y >= height:
        problem = "lies outside the image"
    elif x + w > width or y + h > height:
        problem = f"reaches outside the image (x + width = {x + w}, y + height = {y + h})"
    else:
        mask = np.zeros((height, width), np.uint8)
        mask[y: y + h, x: x + w] = 1
        return mask
    raise ModelError(f"--roi {x},{y},{w},{h} {problem}; the image is {width}x{height} pixels: give a box inside it "
                     f"(x, y >= 0, width, height >= 1, x + width <= {width}, y + height <= {height})")


def read_image(path) -> np.ndarray:
    """(H, W, 3) uint8 RGB of an image file for ``spm predict``; ImageError with the reason alone.
    Not a regular file (a FIFO, /dev/zero) or over MAX_IMAGE_BYTES: refused before reading."""
    return decode_bytes(read_image_file(path))


def read_mask(path) -> np.ndarray:
    """(H, W) bool object mask of ``--mask`` (non-zero = object); ModelError naming it."""
    try:
        m = decode_bytes(read_image_file(path), mode="raw")
    except ImageError as exc:
        raise ModelError(f"--mask {path}: {exc}") from None
    if m.ndim == 3:  # colour: any non-zero colour channel (alpha ignored)
        m = m[..., :3] if m.shape[2] >= 3 else m[..., :1]
        m = m.max(axis=2)
    mask = m > 0
    if not mask.any():
        raise ModelError(f"--mask {path}: no object pixel (every value is 0); give a mask with the object non-zero")
    return mask


def predict_images(model_path, images, *, roi=None, mask_path=None, progress=None, device=None) -> list[dict]:
    """One result per image, in order: {"image", "pose": {rx..tz}[, "keypoints", "eccentricity"]},
    or {"image", "error": reason} when that image cannot be read (missing, not an image,
    truncated, over Pillow's decompression-bomb limit), the region of interest does not fit
    it, or the model finds no pose in it. The model and ``mask_path`` are read first: a
    problem with either raises ModelError (no image is read). progress: a callable taking image
    deltas (feature_cache.progress_phase: "predict", one per image). device: where a cnn model runs
    (evaluate.load_model)."""
    model = load_model(model_path, device)
    mask = read_mask(mask_path) if mask_path is not None else None
    results = []
    progress_phase(progress, "predict", len(images), "image")
    for image in images:
        try:
            rgb = read_image(image)
            h, w = rgb.shape[:2]
            this_mask = roi_mask(roi, w, h) if roi is not None else mask
            if this_mask is not None and this_mask.shape != (h, w):
                raise ModelError(f"--mask {mask_path} is {this_mask.shape[1]}x{this_mask.shape[0]} pixels, the image "
                                 f"{w}x{h}; give a mask of the image's size")
            out = model.predict_image(rgb, this_mask)
            pose = np.asarray(out["pose"], dtype=np.float64)
            if pose.shape != (6,) or not np.isfinite(pose).all():
                raise ModelError("the model found no pose (no object in the mask or region of interest)")
            results.append({"image": str(image), "pose": dict(zip(LABEL_NAMES, map(float, pose))),
                            **({"keypoints": int(out["keypoints"]), "eccentricity": float(out["eccentricity"])}
                               if "keypoints" in out else {})})
        except (ImageError, FeatureError, ModelError) as exc:
            results.append({"image": str(image), "error": one_line(exc)})
        if progress is not None:
            progress(1)
    return results


def printable(name: str) -> str:
    """A file name as one line of text: control characters (a newline, a tab, an escape) written
    as Python escapes (\\n, \\t, \\x1b) and backslashes doubled, so a name can neither split a
    result line nor forge another; other names unchanged. (--json keeps the name exact.)"""
    if not any(ord(c) < 32 or ord(c) == 127 or c == "\\" for c in name):
        return name
    return repr(name)[1:-1].replace("\\'", "'")


def format_predictions(results: list[dict], as_json: bool) -> str:
    """What ``spm predict`` prints on stdout: JSON of every result (failed images as
    {"image", "error"}), or one text line per image that got a pose ("" if none did)."""
    if as_json:
        return json.dumps(results, indent=2)
    lines = []
    for r in results:
        if "error" not in r:
            p = r["pose"]
            extra = f"  [{r['keypoints']} keypoints]" if "keypoints" in r else ""
            lines.append(f"{printable(r['image'])}: rx {p['rx']:.1f} ry {p['ry']:.1f} rz {p['rz']:.1f} deg, "
                         f"t ({p['tx']:.3f}, {p['ty']:.3f}, {p['tz']:.3f}) m{extra}")
    return "\n".join(lines)


def prediction_errors(results: list[dict]) -> list[str]:
    """One line per failed image, in order, for stderr: "IMAGE: reason" (the CLI adds "error: ")."""
    return [f"{printable(r['image'])}: {r['error']}" for r in results if "error" in r]

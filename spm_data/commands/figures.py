"""Figures a person checks a dataset by: contact sheets of a shard's frames with the pose axes drawn
from K, R, t (`spm-data show`), and histograms of occluded fractions (`spm-data hist`)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from spm_data.errors import ShardError, SpmError
from spm_data.core.poses import project_points
from spm_data.io.outputs import check_creatable, removing_created, space_fix
from spm_data.io.files import atomic_file
from spm_data.io.shards import read_attrs, read_shard, shard_layout

AXIS_COLOURS = ((255, 40, 40), (40, 255, 40), (60, 120, 255))  # x red, y green, z blue (RGB)
IMAGE_TYPES = {".png": "png", ".jpg": "jpeg", ".jpeg": "jpeg", ".pdf": "pdf", ".svg": "svg"}  # extension: format


def check_image_path(path, example: str = "sheet.png") -> Path:
    """``path`` as a Path when it names an image this module writes (an extension of
    IMAGE_TYPES) in a folder that is, or can be made, writable; else a one-line SpmError.
    Creates nothing: for checking before any work is done."""
    path = Path(path)
    if path.is_dir():
        raise SpmError(f"{path} is a folder; give an image file name such as {path / example}")
    if path.suffix.lower() not in IMAGE_TYPES:
        got = f"unsupported extension {path.suffix!r}" if path.suffix else "no extension"
        raise SpmError(f"{path}: {got}; give a file name ending in {', '.join(IMAGE_TYPES)}")
    check_creatable(path, "write", "give --out a path in a folder", "give --out a path in a writable folder")
    return path


def save_image(path: Path, write) -> Path:
    """Write ``path`` atomically: ``write(binary file)`` fills a temporary file beside it, which
    then replaces ``path``. On any failure nothing is left, nor the folders made for it; an
    OSError (read-only, disk full) becomes a one-line SpmError."""
    path = Path(path)
    try:
        with removing_created(path):
            path.parent.mkdir(parents=True, exist_ok=True)
            with atomic_file(path) as tmp, open(tmp, "wb") as fh:
                write(fh)
                fh.flush()
                os.fsync(fh.fileno())
    except OSError as exc:
        fix = space_fix(exc, "give --out a path in a writable folder")
        raise SpmError(f"could not write {path}: {exc.strerror or exc}; {fix}") from None
    return path


def draw_pose(image: np.ndarray, K, R, t, length: float, scale: int = 1) -> np.ndarray:
    """Draw the object frame's axes (``length`` metres) on an RGB image upscaled by ``scale``."""
    import cv2

    pts = np.array([[0, 0, 0], [length, 0, 0], [0, length, 0], [0, 0, length]], dtype=np.float64)
    uv, z = project_points(pts, K, R, t)
    if np.any(z <= 0) or not np.all(np.isfinite(uv)):
        return image
    uv = (uv + 0.5) * scale - 0.5  # OpenCV pixel centres survive the upscale
    origin = tuple(int(round(c)) for c in uv[0])
    for end, colour in zip(uv[1:], AXIS_COLOURS):
        cv2.line(image, origin, tuple(int(round(c)) for c in end), colour, 2, lineType=cv2.LINE_AA)
    return image


SHEET_FIELDS = ("rgb", "normals", "instances", "coords", "depth")
INSTANCE_COLOURS = np.array([[0, 0, 0], [255, 220, 0], [60, 140, 255], [255, 80, 160], [80, 230, 120],
                             [200, 120, 255], [255, 150, 60], [120, 230, 230]], np.uint8)


def false_colour(field: str, frame: np.ndarray, size: float) -> np.ndarray:
    """(H, W, 3) uint8 picture of one frame of an image field: normals as (n + 1) / 2,
    instance ids in fixed colours, object coordinates (metres, object of ``size``)
    as NOCS colours, depth as grey (near light)."""
    if field == "normals":
        return np.round((frame.astype(np.float32) + 1) * 127.5).astype(np.uint8) * np.any(frame != 0, -1)[..., None]
    if field == "instances":
        return INSTANCE_COLOURS[np.minimum(frame, len(INSTANCE_COLOURS) - 1)]
    if field == "coords":
        seen = np.any(frame != 0, -1)[..., None]
        return (np.clip(frame.astype(np.float32) / size + 0.5, 0, 1) * 255).astype(np.uint8) * seen
    hit = frame > 0
    if not hit.any():
        return np.zeros(frame.shape + (3,), np.uint8)
    lo, hi = frame[hit].min(), frame[hit].max()
    grey = np.where(hit, 255 - 200 * (frame - lo) / max(hi - lo, 1e-9), 0).astype(np.uint8)
    return np.repeat(grey[..., None], 3, axis=-1)


def contact_sheet(shard, out_png, frames: int = 24, columns: int = 6, scale: int = 2, field: str = "rgb") -> Path:
    """Write an image (PNG, JPEG, PDF or SVG, by ``out_png``'s extension) of a grid of
    ``frames`` evenly spaced frames of ``shard``; returns its path. ``field``: what the
    tiles show (SHEET_FIELDS): the rgb image, or a field in false colour. The target's
    outline is yellow, its visible part's (distractors, occlusion) green."""
    import cv2

    out_png = check_image_path(out_png, "sheet.png")
    if field not in SHEET_FIELDS:
        raise SpmError(f"field {field!r}: expected one of {', '.join(SHEET_FIELDS)}")
    attrs = read_attrs(shard)
    n = int(attrs["frames"])
    if n == 0:
        raise ShardError(f"{shard}: shard has no frames")
    layout = shard_layout(shard)
    if field not in layout:
        raise ShardError(f"{shard}: has no {field} field; render it with [outputs] {field} = true")
    pick = np.unique(np.round(np.linspace(0, n - 1, min(frames, n))).astype(int))
    extra = [f for f in ("visible_mask", "occlusion_fraction") if f in layout and f != field]
    data = read_shard(shard, list(dict.fromkeys(["rgb", "mask", "K", "R", "t", "azimuth", "elevation", "distance",
                                                 "occlusion_rects", field, *extra])), frames=pick)
    length = 0.5 * float(attrs.get("object_size", 0.2))
    tiles = []
    for i in range(len(pick)):
        tile = data["rgb"][i] if field == "rgb" else false_colour(field, data[field][i], 2 * length)
        img = np.ascontiguousarray(cv2.resize(tile, None, fx=scale, fy=scale, interpolation=cv2.INTER_NEAREST))
        outlines = [("mask", (255, 220, 0))] + ([("visible_mask", (60, 255, 60))] if "visible_mask" in data else [])
        for key, colour in outlines:
            mask = cv2.resize(data[key][i], None, fx=scale, fy=scale, interpolation=cv2.INTER_NEAREST)
            contours, _ = cv2.findContours(mask.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
            cv2.drawContours(img, contours, -1, colour, 1)
        for x0, y0, x1, y1 in data["occlusion_rects"][i]:
            if x1 > x0 and y1 > y0:
                cv2.rectangle(img, (int(x0) * scale, int(y0) * scale), (int(x1) * scale - 1, int(y1) * scale - 1),
                              (255, 0, 255), 1)
        draw_pose(img, data["K"][i], data["R"][i], data["t"][i], length, scale)
        caption = f"#{pick[i]} az{data['azimuth'][i]:.0f} el{data['elevation'][i]:.0f} d{data['distance'][i]:.2f}"
        if "visible_mask" in data:
            caption += f" v{1 - data['occlusion_fraction'][i]:.2f}"
        cv2.putText(img, caption, (3, 12), cv2.FONT_HERSHEY_SIMPLEX, 0.35, (255, 255, 255), 1, cv2.LINE_AA)
        tiles.append(img)
    h, w = tiles[0].shape[:2]
    rows = -(-len(tiles) // columns)
    sheet = np.full((rows * (h + 2), min(columns, len(tiles)) * (w + 2), 3), 40, np.uint8)
    for k, tile in enumerate(tiles):
        r, c = divmod(k, columns)
        sheet[r * (h + 2):r * (h + 2) + h, c * (w + 2):c * (w + 2) + w] = tile
    fmt = IMAGE_TYPES[out_png.suffix.lower()]
    if fmt in ("png", "jpeg"):
        ok, encoded = cv2.imencode(".png" if fmt == "png" else ".jpg", cv2.cvtColor(sheet, cv2.COLOR_RGB2BGR))
        if not ok:
            raise SpmError(f"could not encode {out_png} as {fmt.upper()}")
        return save_image(out_png, lambda fh: fh.write(encoded.tobytes()))
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.image import imsave

    return save_image(out_png, lambda fh: imsave(fh, sheet, format=fmt))


def occlusion_histogram(folder, out_png, bins: int = 30, allow_partial: bool = False) -> Path:
    """Histogram (PNG, JPEG, PDF or SVG, by ``out_png``'s extension) of the per-frame covered
    fractions of every shard in ``folder``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from spm_data.io.folders import open_folder

    out_png = check_image_path(out_png, "occlusion-hist.png")
    shards = open_folder(folder, allow_partial=allow_partial).shards
    fractions = np.concatenate([read_shard(p, ["occlusion_fraction"])["occlusion_fraction"] for p in shards])
    fig, ax = plt.subplots(figsize=(6, 3.2), dpi=100)
    ax.hist(fractions, bins=bins, range=(0, 1), color="#4a7ab0", edgecolor="white")
    ax.set_xlabel("fraction of the object's mask covered")
    ax.set_ylabel("frames")
    ax.set_title(f"{len(fractions)} frames, {len(shards)} shards: min {fractions.min():.3f}, "
                 f"max {fractions.max():.3f}", fontsize=9)
    fig.tight_layout()
    try:
        return save_image(out_png, lambda fh: fig.savefig(fh, format=IMAGE_TYPES[out_png.suffix.lower()]))
    finally:
        plt.close(fig)

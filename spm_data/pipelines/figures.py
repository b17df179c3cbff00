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
from spm_data.io.shards import read_shard

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


def draw_pose(image: np.ndarray, K, R, t, length: float, scale: float = 1) -> np.ndarray:
    """Draw the object frame's axes (``length`` metres) on an RGB image resized by ``scale``."""
    import cv2

    pts = np.array([[0, 0, 0], [length, 0, 0], [0, length, 0], [0, 0, length]], dtype=np.float64)
    uv, z = project_points(pts, K, R, t)
    if np.any(z <= 0) or not np.all(np.isfinite(uv)):
        return image
    uv = (uv + 0.5) * scale - 0.5  # OpenCV pixel centres survive the resize
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


TILE_SIDE = 256  # pixels: the longer side of a contact sheet's tile, whatever the frames' size


def contact_sheet(shard, out_png, frames: int = 24, columns: int = 6, scale: float | None = None,
                  field: str = "rgb", tile: int = TILE_SIDE) -> Path:
    """Write an image (PNG, JPEG, PDF or SVG, by ``out_png``'s extension) of a grid of
    ``frames`` evenly spaced frames of ``shard``; returns its path. ``field``: what the
    tiles show (SHEET_FIELDS): the rgb image, or a field in false colour. Each tile is the frame
    scaled so its longer side is ``tile`` pixels (``scale``: by that factor instead). The target's
    outline is yellow, its visible part's (distractors, occlusion) green; the pose axes are drawn
    from K, R, t; captions give the camera's azimuth, elevation and distance (metres), from R and t
    where the shard leaves them NaN (imports). A progress line on stderr counts the tiles."""
    from spm_data.jobs.progress import Progress
    from spm_data.io.shards import ShardReader

    out_png = check_image_path(out_png, "sheet.png")
    if field not in SHEET_FIELDS:
        raise SpmError(f"field {field!r}: expected one of {', '.join(SHEET_FIELDS)}")
    with ShardReader(shard) as reader:
        attrs, layout = reader.attrs, reader.layout()
        n = int(attrs["frames"])
        if n == 0:
            raise ShardError(f"{shard}: shard has no frames")
        if field not in layout:
            raise ShardError(f"{shard}: has no {field} field; render it with [outputs] {field} = true")
        pick = np.unique(np.round(np.linspace(0, n - 1, min(frames, n))).astype(int))
        extra = [f for f in ("visible_mask", "occlusion_fraction") if f in layout and f != field]
        fields = list(dict.fromkeys(["rgb", "mask", "K", "R", "t", "azimuth", "elevation", "distance",
                                     "occlusion_rects", field, *extra]))
        h, w = layout["rgb"][0][1:3]
        factor = float(scale) if scale else tile / max(h, w)
        size = (max(1, round(w * factor)), max(1, round(h * factor)))
        tiles = []
        with Progress("frame", "show", len(pick)) as progress:
            for k in pick:
                tiles.append(_tile(reader.read(fields, frames=int(k)), int(k), field, attrs, size))
                progress(1)
    return _write_sheet(tiles, columns, out_png)


def _tile(frame: dict, index: int, field: str, attrs: dict, size: tuple) -> np.ndarray:
    """One frame's tile of ``size`` (width, height): the picture, outlines, occluders, axes, caption."""
    import cv2

    h, w = frame["rgb"].shape[:2]
    sx, sy = size[0] / w, size[1] / h
    picture = frame["rgb"] if field == "rgb" else false_colour(field, frame[field], _axis_length(frame, attrs) * 2)
    shrink = cv2.INTER_AREA if sx < 1 else cv2.INTER_NEAREST
    img = np.ascontiguousarray(cv2.resize(picture, size, interpolation=shrink))
    outlines = [("mask", (255, 220, 0))] + ([("visible_mask", (60, 255, 60))] if "visible_mask" in frame else [])
    for key, colour in outlines:
        mask = cv2.resize(frame[key].astype(np.uint8), size, interpolation=cv2.INTER_NEAREST)
        contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
        cv2.drawContours(img, contours, -1, colour, 1)
    for x0, y0, x1, y1 in frame["occlusion_rects"]:
        if x1 > x0 and y1 > y0:
            cv2.rectangle(img, (int(x0 * sx), int(y0 * sy)), (int(x1 * sx) - 1, int(y1 * sy) - 1), (255, 0, 255), 1)
    draw_pose(img, frame["K"], frame["R"], frame["t"], _axis_length(frame, attrs), sx)
    cv2.putText(img, _caption(frame, index), (3, 12), cv2.FONT_HERSHEY_SIMPLEX, 0.35, (255, 255, 255), 1,
                cv2.LINE_AA)
    return img


def _axis_length(frame: dict, attrs: dict) -> float:
    """Metres: half the rendered object's size; for an import (no object_size), what spans a fifth of
    the frame's longer side at the object's depth."""
    if "object_size" in attrs:
        return 0.5 * float(attrs["object_size"])
    depth = float(frame["t"][2]) if frame["t"][2] > 0 else float(np.linalg.norm(frame["t"]))
    return 0.2 * max(frame["rgb"].shape[:2]) * depth / max(float(frame["K"][0, 0]), 1e-9)


def _caption(frame: dict, index: int) -> str:
    """"#INDEX az.. el.. d..m [v..]": the stored path point, or where the camera centre is seen
    from the object origin (R, t) for what the shard leaves NaN; never NaN."""
    centre = -np.asarray(frame["R"]).T @ np.asarray(frame["t"])
    distance = float(np.linalg.norm(centre))
    az, el, d = (float(frame[k]) for k in ("azimuth", "elevation", "distance"))
    if not (np.isfinite(az) and np.isfinite(el)):
        az = float(np.degrees(np.arctan2(centre[1], centre[0])))
        el = float(np.degrees(np.arcsin(np.clip(centre[2] / max(distance, 1e-300), -1, 1))))
    d = d if np.isfinite(d) else distance
    caption = f"#{index} az{az:.0f} el{el:.0f} d{d:.2f}m"
    if "visible_mask" in frame:
        caption += f" v{1 - float(frame['occlusion_fraction']):.2f}"
    return caption


def _write_sheet(tiles: list, columns: int, out_png: Path) -> Path:
    import cv2

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

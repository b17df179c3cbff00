"""What every importer shares: frame records, robust image reading, shards of imported frames.

An importer lists :class:`FrameRecord` s (one per output frame: where its image
is, its pose, intrinsics, class, and which label components are measured);
:func:`import_records` groups them by image size into shards and writes them
through the resumable shard run. Unreadable images are skipped and listed,
never fatal.
"""

from __future__ import annotations

import hashlib
import io
import json
import re
import tarfile
import zipfile
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from spm_data import __version__
from spm_data.errors import SpmError, one_line
from spm_data.poses import is_rotation, pose_to_label
from spm_data.shard_runs import RunSummary, run_shard_jobs
from spm_data.shards import SCHEMA_VERSION, manifest_entry, write_shard

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".ppm", ".pgm", ".bmp", ".tif", ".tiff")
NAN3 = (float("nan"),) * 3


class ImageError(SpmError):
    """An image that cannot be read (truncated, foreign, empty)."""


@dataclass(frozen=True)
class FrameRecord:
    """One frame to import. ``image``/``mask``: references for :func:`read_bytes`
    (a path, ``zip:ARCHIVE::MEMBER`` or ``tar:ARCHIVE::MEMBER``). R (3, 3) and t (3,)
    metres map object to OpenCV camera; K (3, 3); tuples so records hash."""

    image: str
    class_name: str
    instance_name: str
    instance_id: int
    R: tuple
    t: tuple
    K: tuple
    label_measured: tuple = (True,) * 6
    azimuth: float = float("nan")
    elevation: float = float("nan")
    roll: float = float("nan")
    distance: float = float("nan")
    path_index: int = -1
    mask: str | None = None            # a mask image; None: derive by threshold
    visible_mask: str | None = None    # the object's visible part, where the source has it (BOP)
    depth: str | None = None           # a uint16 depth image; None: no depth (zeros)
    depth_scale_m: float = 0.001       # metres per depth unit
    crop: str | None = None            # "mask": a square around the object's mask, resized to --size


# --------------------------------------------------------------------------- reading

def read_bytes(ref: str) -> bytes:
    """The bytes behind an image reference (a file, or a member of a zip or tar archive)."""
    try:
        if ref.startswith("zip:"):
            archive, member = ref[4:].split("::", 1)
            with zipfile.ZipFile(archive) as zf:
                return zf.read(member)
        if ref.startswith("tar:"):
            archive, member = ref[4:].split("::", 1)
            with tarfile.open(archive) as tf:
                handle = tf.extractfile(member)
                if handle is None:
                    raise ImageError(f"{ref}: not a file in the archive")
                return handle.read()
        return Path(ref).read_bytes()
    except (OSError, KeyError, zipfile.BadZipFile, tarfile.TarError) as exc:
        raise ImageError(f"{ref}: cannot read ({exc})") from None


def parse_pnm(data: bytes) -> np.ndarray:
    """Netpbm P5/P6 (binary grey/RGB), 8 or 16 bits, with comments and any whitespace
    in the header. Returns (H, W, 3) uint8 (16-bit values scaled by 255 / maxval)."""
    fields, pos = [], 0
    while len(fields) < 4:
        while pos < len(data) and data[pos:pos + 1].isspace():
            pos += 1
        if data[pos:pos + 1] == b"#":  # a comment runs to the end of the line
            end = data.find(b"\n", pos)
            pos = len(data) if end < 0 else end + 1
            continue
        m = re.match(rb"\S+", data[pos:])
        if not m:
            raise ImageError("PNM header ends early")
        fields.append(m.group(0))
        pos += len(m.group(0))
    pos += 1  # exactly one whitespace byte before the raster
    magic = fields[0]
    if magic not in (b"P5", b"P6"):
        raise ImageError(f"not a binary PNM image (magic {magic[:4]!r})")
    try:
        w, h, maxval = (int(x) for x in fields[1:])
    except ValueError:
        raise ImageError("PNM header has a non-number size") from None
    if w <= 0 or h <= 0 or not 0 < maxval < 65536:
        raise ImageError(f"PNM header out of range ({w}x{h}, maxval {maxval})")
    channels = 3 if magic == b"P6" else 1
    dtype = np.dtype(">u2") if maxval > 255 else np.dtype(np.uint8)
    need = w * h * channels * dtype.itemsize
    if len(data) - pos < need:
        raise ImageError(f"PNM image is truncated ({len(data) - pos} of {need} bytes)")
    raster = np.frombuffer(data, dtype=dtype, count=w * h * channels, offset=pos).reshape(h, w, channels)
    if maxval != 255:
        raster = np.round(raster.astype(np.float64) * (255.0 / maxval))
    raster = raster.astype(np.uint8)
    return np.repeat(raster, 3, axis=2) if channels == 1 else raster


def _bomb_reason(exc) -> str:
    from PIL import Image

    m = re.search(r"\((\d+) pixels\)", str(exc))
    size = f"{int(m.group(1)):,} pixels" if m else "the image"
    return (f"{size} is over the decompression-bomb limit of {Image.MAX_IMAGE_PIXELS:,} pixels "
            "(Pillow's PIL.Image.MAX_IMAGE_PIXELS); downscale the image")


@contextmanager
def _open_image(data: bytes):
    """Pillow's image of ``data``, decompression bombs (its error and its warning) and
    foreign or truncated data as ImageError with a reason (no file name)."""
    import warnings

    from PIL import Image, UnidentifiedImageError

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error", Image.DecompressionBombWarning)
            with Image.open(io.BytesIO(data)) as img:
                yield img
    except (Image.DecompressionBombError, Image.DecompressionBombWarning) as exc:
        raise ImageError(_bomb_reason(exc)) from None
    except UnidentifiedImageError:
        raise ImageError("not a readable image (unknown format, or a truncated header)") from None
    except (OSError, SyntaxError, ValueError, EOFError) as exc:
        raise ImageError(f"not a readable image (truncated or corrupt: {one_line(exc)})") from None


def _tile_rawmode(img) -> str:
    """The raw mode Pillow will decode the file's pixels from ("RGB;16B": 16-bit colour); "" if unknown."""
    try:
        args = img.tile[0].args if hasattr(img.tile[0], "args") else img.tile[0][3]
        return str(args[0] if isinstance(args, tuple) else args)
    except (IndexError, TypeError, AttributeError):
        return ""


def from_16_bit(values: np.ndarray) -> np.ndarray:
    """16-bit samples -> uint8 by the fixed scale round(value / 257) (65535 -> 255, v * 257 -> v):
    never stretched per image, so an 8-bit image and its 16-bit copy give the same pixels."""
    return np.round(np.clip(np.asarray(values, dtype=np.float64), 0, 65535) / 257.0).astype(np.uint8)


def decode_bytes(data: bytes, mode: str = "RGB") -> np.ndarray:
    """:func:`decode_image` without the name: ImageError's message is the reason alone."""
    if not data:
        raise ImageError("empty file")
    if data[:2] in (b"P5", b"P6") and mode == "RGB":
        return parse_pnm(data)
    with _open_image(data) as img:
        rawmode = _tile_rawmode(img)
        img.load()  # decodes everything: a truncated file raises here
        if mode != "RGB":
            return np.asarray(img)
        if img.mode in ("I;16", "I;16B", "I;16L", "I;16N", "I"):  # 16-bit grey (32-bit "I": clipped to 16)
            return np.repeat(from_16_bit(np.asarray(img))[..., None], 3, axis=2)
        if img.mode in ("RGB", "RGBA") and ";16" in rawmode:
            # Pillow keeps 16-bit colour's high byte; OpenCV reads all 16 bits, scaled as grey is.
            import cv2

            full = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
            if full is not None and full.dtype == np.uint16 and full.ndim == 3 and full.shape[2] in (3, 4) \
                    and full.shape[:2] == (img.height, img.width):
                return from_16_bit(full[..., 2::-1])
        return np.asarray(img.convert("RGB"), dtype=np.uint8)


def decode_image(data: bytes, name: str = "", mode: str = "RGB") -> np.ndarray:
    """(H, W, 3) uint8 RGB (mode "RGB") or (H, W) array as stored ("raw", e.g. uint16
    depth or a mask). 16-bit images (grey, colour, PNM) become 8 bits by round(value / 257).
    Empty, truncated or foreign data and images over Pillow's decompression-bomb limit
    raise ImageError ("NAME: reason")."""
    try:
        return decode_bytes(data, mode)
    except ImageError as exc:
        raise ImageError(f"{name}: {exc}") from None


def image_size(ref: str) -> tuple[int, int]:
    """(width, height) from the header only."""
    data = read_bytes(ref)
    try:
        if data[:2] in (b"P5", b"P6"):
            img = parse_pnm(data)
            return img.shape[1], img.shape[0]
        if not data:
            raise ImageError("empty file")
        with _open_image(data) as img:
            return img.size
    except ImageError as exc:
        raise ImageError(f"{ref}: {exc}") from None


def threshold_mask(rgb: np.ndarray, threshold: int) -> np.ndarray:
    """(H, W) uint8 mask of pixels whose brightest channel exceeds ``threshold`` (0..255)."""
    return (rgb.max(axis=2) > threshold).astype(np.uint8)


# --------------------------------------------------------------------------- shards of imported frames

@dataclass(frozen=True)
class ImportJob:
    name: str
    plan_key: str
    out_dir: str
    records: tuple = field(repr=False)
    source: str = ""
    threshold: int = 10
    size: tuple | None = None       # (width, height) to resize crops to
    attrs_json: str = "{}"

    @property
    def frames(self) -> int:
        return len(self.records)


def _load_frame(rec: FrameRecord, job: ImportJob):
    import cv2

    rgb = decode_image(read_bytes(rec.image), rec.image)
    h, w = rgb.shape[:2]
    mask = None
    if rec.mask is not None:
        m = decode_image(read_bytes(rec.mask), rec.mask, mode="raw")
        mask = (m.max(axis=2) if m.ndim == 3 else m) > 0
        if mask.shape != (h, w):
            raise ImageError(f"{rec.mask}: mask is {mask.shape[1]}x{mask.shape[0]}, image is {w}x{h}")
        mask = mask.astype(np.uint8)
    visible = mask
    if rec.visible_mask is not None:
        v = decode_image(read_bytes(rec.visible_mask), rec.visible_mask, mode="raw")
        visible = ((v.max(axis=2) if v.ndim == 3 else v) > 0).astype(np.uint8)
    depth = np.zeros((h, w), np.float32)
    if rec.depth is not None:
        d = decode_image(read_bytes(rec.depth), rec.depth, mode="raw")
        if d.shape != (h, w):
            raise ImageError(f"{rec.depth}: depth is {d.shape[1]}x{d.shape[0]}, image is {w}x{h}")
        depth = (d.astype(np.float64) * rec.depth_scale_m).astype(np.float32)
    if mask is None:
        mask = threshold_mask(rgb, job.threshold)
    if visible is None:
        visible = mask
    K = np.array(rec.K, dtype=np.float64).reshape(3, 3)
    if rec.crop == "mask":
        ys, xs = np.nonzero(mask)
        if len(ys) == 0:
            raise ImageError(f"{rec.image}: the object's mask is empty; nothing to crop around")
        cx, cy = (xs.min() + xs.max() + 1) / 2, (ys.min() + ys.max() + 1) / 2
        half = int(np.ceil(max(xs.max() - xs.min() + 1, ys.max() - ys.min() + 1) * 0.6))
        x0, y0 = int(round(cx)) - half, int(round(cy)) - half
        x1, y1 = x0 + 2 * half, y0 + 2 * half
        pad = max(0, -x0, -y0, x1 - w, y1 - h)  # squares near the border are padded with black
        if pad:
            rgb, mask, visible, depth = (np.pad(a, ((pad, pad), (pad, pad)) + ((0, 0),) * (a.ndim - 2))
                                         for a in (rgb, mask, visible, depth))
        X0, Y0 = x0 + pad, y0 + pad
        tw, th = job.size or (x1 - x0, y1 - y0)
        sx, sy = tw / (x1 - x0), th / (y1 - y0)
        rgb = cv2.resize(rgb[Y0:Y0 + 2 * half, X0:X0 + 2 * half], (tw, th), interpolation=cv2.INTER_AREA)
        mask = cv2.resize(mask[Y0:Y0 + 2 * half, X0:X0 + 2 * half], (tw, th), interpolation=cv2.INTER_NEAREST)
        visible = cv2.resize(visible[Y0:Y0 + 2 * half, X0:X0 + 2 * half], (tw, th),
                             interpolation=cv2.INTER_NEAREST)
        depth = cv2.resize(depth[Y0:Y0 + 2 * half, X0:X0 + 2 * half], (tw, th), interpolation=cv2.INTER_NEAREST)
        # The crop's pixel centres: u' = (u - x0 + 0.5) * sx - 0.5.
        K = np.array([[K[0, 0] * sx, 0, (K[0, 2] - x0 + 0.5) * sx - 0.5],
                      [0, K[1, 1] * sy, (K[1, 2] - y0 + 0.5) * sy - 0.5], [0, 0, 1.0]])
    return rgb, mask, depth, K, visible


def import_shard(job: ImportJob, report=lambda n: None) -> dict:
    """Read the job's frames (skipping unreadable ones, listed) and write its shard."""
    frames, skipped = [], []
    for rec in job.records:
        try:
            frames.append((rec, *_load_frame(rec, job)))
        except ImageError as exc:
            skipped.append([rec.image, str(exc)])
        report(1)
    if not frames:
        return {"entry": None, "skipped": skipped, "frames": 0}
    sizes = {f[1].shape for f in frames}
    if len(sizes) > 1:
        raise SpmError(f"{job.name}: images of different sizes {sorted(sizes)} in one shard; pass --size WxH")
    n = len(frames)
    R = np.array([f[0].R for f in frames], dtype=np.float64).reshape(n, 3, 3)
    t = np.array([f[0].t for f in frames], dtype=np.float64).reshape(n, 3)
    arrays = {
        "rgb": np.stack([f[1] for f in frames]), "depth": np.stack([f[3] for f in frames]),
        "mask": np.stack([f[2] for f in frames]), "K": np.stack([f[4] for f in frames]), "R": R, "t": t,
        "pose": pose_to_label(R, t).reshape(n, 6),
        "azimuth": np.array([f[0].azimuth for f in frames]), "elevation": np.array([f[0].elevation for f in frames]),
        "roll": np.array([f[0].roll for f in frames]), "distance": np.array([f[0].distance for f in frames]),
        "look_at": np.zeros((n, 3)), "path_index": np.array([f[0].path_index for f in frames], dtype=np.int64),
        "instance_id": np.array([f[0].instance_id for f in frames], dtype=np.int64),
        "instance_name": [f[0].instance_name for f in frames], "class_name": [f[0].class_name for f in frames],
        "source": [job.source] * n, "label_measured": np.array([f[0].label_measured for f in frames], dtype=bool),
        "occlusion_fraction": np.zeros(n, np.float32), "occlusion_rects": np.zeros((n, 1, 4), np.int32),
        "source_shard": [f[0].image for f in frames], "source_frame": np.arange(n, dtype=np.int64),
    }
    if any(f[0].visible_mask is not None for f in frames):
        visible = np.stack([f[5] for f in frames])
        full = arrays["mask"].reshape(n, -1).sum(axis=1)
        arrays["visible_mask"] = visible
        arrays["occlusion_fraction"] = np.where(
            full > 0, 1.0 - visible.reshape(n, -1).sum(axis=1) / np.maximum(full, 1), 0.0).astype(np.float32)
    attrs = {**json.loads(job.attrs_json), "plan_key": job.plan_key, "renderer": "none (imported)",
             "seed": 0, "source": job.source, "spm_version": __version__, "import_skipped": json.dumps(skipped)}
    target = write_shard(Path(job.out_dir) / job.name, arrays, attrs)
    return {"entry": manifest_entry(target), "skipped": skipped, "frames": n}


def check_fov_option(fov) -> None:
    """SpmError unless ``--fov`` is a vertical field of view in (0, 180) degrees (NaN is not)."""
    if not 0 < fov < 180:
        raise SpmError(f"--fov {fov}: expected a vertical field of view in (0, 180) degrees")


def pose_problem(R, t, K=None) -> str | None:
    """Why a pose (R (3, 3), t (3,) metres, K (3, 3) or None) cannot be imported, or None:
    non-finite values, R not a rotation, fx or fy not > 0. Importers call it before writing."""
    R = np.asarray(R, dtype=np.float64).reshape(3, 3)
    t = np.asarray(t, dtype=np.float64).reshape(3)
    fmt = lambda a: "[" + ", ".join(f"{v:g}" for v in np.ravel(a)) + "]"  # noqa: E731
    if not np.isfinite(R).all():
        return f"the rotation has a non-finite value (R = {fmt(R)}); expected finite numbers"
    if not is_rotation(R):
        return f"R = {fmt(R)} is not a rotation matrix (orthonormal, determinant +1)"
    if not np.isfinite(t).all():
        return f"the translation has a non-finite value (t = {fmt(t)}); expected finite numbers"
    if K is not None:
        K = np.asarray(K, dtype=np.float64).reshape(3, 3)
        if not np.isfinite(K).all():
            return f"the intrinsics have a non-finite value (K = {fmt(K)}); expected finite fx, fy, cx, cy"
        if not (K[0, 0] > 0 and K[1, 1] > 0):
            return f"focal length fx = {K[0, 0]:g}, fy = {K[1, 1]:g}; expected fx, fy > 0 pixels"
    return None


def check_records(records) -> None:
    """SpmError naming the first record whose pose or intrinsics cannot be imported (see pose_problem)."""
    for rec in records:
        problem = pose_problem(rec.R, rec.t, rec.K)
        if problem is not None:
            raise SpmError(f"{rec.image}: {problem}; correct its pose or intrinsics (nothing was written)")


def import_records(records, out_dir, *, source: str, prefix: str, frames_per_shard=256, threshold=10,
                   size=None, attrs=None, workers=1, progress=None, executor=None) -> RunSummary:
    """Write ``records`` as shards ``PREFIX-NNNNN.h5`` in ``out_dir`` (resuming)."""
    if not records:
        raise SpmError("nothing to import: no frames were found")
    check_records(records)  # every pose before the first shard: a bad one writes nothing
    attrs_json = json.dumps(attrs or {}, sort_keys=True)
    key_base = json.dumps([SCHEMA_VERSION, source, threshold, size, attrs_json], sort_keys=True)
    jobs = []
    for i, start in enumerate(range(0, len(records), frames_per_shard)):
        chunk = tuple(records[start:start + frames_per_shard])
        key = hashlib.sha256((key_base + repr(chunk)).encode()).hexdigest()
        jobs.append(ImportJob(f"{prefix}-{i:05d}.h5", key, str(out_dir), chunk, source, threshold,
                              tuple(size) if size else None, attrs_json))
    return run_shard_jobs(import_shard, jobs, out_dir, workers=workers, progress=progress, verb="imported",
                          executor=executor)


def import_report(summary: RunSummary, problems=()) -> str:
    """The summary plus every skipped frame and why (listing problems found while planning too)."""
    skipped = [tuple(s) for r in summary.results.values() for s in r.get("skipped", [])] + list(problems)
    details = [f"  skipped {len(skipped)} images:"] + [f"    {name}: {why}" for name, why in skipped[:50]]
    if len(skipped) > 50:
        details.append(f"    ... and {len(skipped) - 50} more")
    return summary.report(details if skipped else ["  skipped 0 images"])

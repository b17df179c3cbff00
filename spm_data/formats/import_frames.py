"""An importer's frames read and written as one shard (spm_data/formats/importing.py plans the
jobs): each frame decoded, undistorted, downscaled (``--max-side``), masked and cropped on
THREADS threads, and streamed to the shard writer BLOCK frames at a time, so the progress counts
frames as they are stored (through the write, not before it) and memory holds a block, not the
shard. A frame that cannot be read is skipped and listed, never fatal.
"""

from __future__ import annotations

import json
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from spm_data.version import __version__
from spm_data.core.poses import pose_to_label, scale_K
from spm_data.errors import SpmError
from spm_data.formats.capture_images import capture_mask, undistort
from spm_data.io.images import ImageError, decode_alpha, decode_image, read_bytes
from spm_data.io.shards import ShardWriter, manifest_entry

THREADS = 2   # frames read at once (decoding, remapping and resizing release the GIL)
BLOCK = 8     # frames per block handed to the writer


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
    max_side: int = 0               # frames larger are downscaled to this longer side (0: never)

    @property
    def frames(self) -> int:
        return len(self.records)


def threshold_mask(rgb: np.ndarray, threshold: int) -> np.ndarray:
    """(H, W) uint8 mask of pixels whose brightest channel exceeds ``threshold`` (0..255)."""
    return (rgb.max(axis=2) > threshold).astype(np.uint8)


def downscale(rgb, planes, K, max_side: int):
    """``rgb`` (H, W, 3) and ``planes`` (masks, depth: (H, W) or None) scaled so the longer side is
    ``max_side`` (area-averaged rgb, nearest-neighbour planes), and K for the new size (exact:
    core/poses.scale_K). Returns (rgb, *planes, K)."""
    import cv2

    h, w = rgb.shape[:2]
    s = max_side / max(h, w)
    size = (max(1, round(w * s)), max(1, round(h * s)))
    out = [cv2.resize(rgb, size, interpolation=cv2.INTER_AREA)]
    out += [None if p is None else cv2.resize(p, size, interpolation=cv2.INTER_NEAREST) for p in planes]
    return (*out, scale_K(K, size[0] / w, size[1] / h))


def _load_frame(rec, job: ImportJob):
    """(rgb, mask, depth, K, visible) of one FrameRecord as its shard stores them; ImageError to skip it."""
    import cv2

    rgb = decode_image(read_bytes(rec.image), rec.image)
    h, w = rgb.shape[:2]
    mask = None
    if rec.mask is not None:
        if rec.mask_alpha:  # the object: at least half opaque
            mask = decode_alpha(read_bytes(rec.mask), rec.mask) >= 128
            if mask.all():
                raise ImageError(f"{rec.mask}: its alpha channel is opaque everywhere, so it holds no mask; give "
                                 "masks with --mask-dir")
        else:
            m = decode_image(read_bytes(rec.mask), rec.mask, mode="raw")
            mask = (m.max(axis=2) if m.ndim == 3 else m) > 0
        if mask.shape != (h, w):
            raise ImageError(f"{rec.mask}: mask is {mask.shape[1]}x{mask.shape[0]}, image is {w}x{h}")
        mask = mask.astype(np.uint8)
    visible = mask
    if rec.visible_mask is not None:
        v = decode_image(read_bytes(rec.visible_mask), rec.visible_mask, mode="raw")
        visible = ((v.max(axis=2) if v.ndim == 3 else v) > 0).astype(np.uint8)
    depth = None   # no depth image: the shard has no depth field (a read of it gives zeros)
    if rec.depth is not None:
        d = decode_image(read_bytes(rec.depth), rec.depth, mode="raw")
        if d.ndim != 2 or d.dtype == np.uint8:   # 8 bits hold 256 depths: not a depth map
            raise ImageError(f"{rec.depth}: depth is an {d.dtype.itemsize * 8}-bit image with "
                             f"{1 if d.ndim == 2 else d.shape[2]} channel(s); expected one 16-bit channel (a "
                             "depth PNG: units x the depth scale)")
        if d.shape != (h, w):
            raise ImageError(f"{rec.depth}: depth is {d.shape[1]}x{d.shape[0]}, image is {w}x{h}")
        depth = (d.astype(np.float64) * rec.depth_scale_m).astype(np.float32)
    if mask is None and not rec.mask_method:
        mask = threshold_mask(rgb, job.threshold)
    K = np.array(rec.K, dtype=np.float64).reshape(3, 3)
    if any(rec.distortion):
        rgb = undistort(rgb, K, rec.distortion, rec.fisheye, nearest=False)
        mask, visible, depth = (None if a is None else undistort(a, K, rec.distortion, rec.fisheye, nearest=True)
                                for a in (mask, visible, depth))
    if job.max_side and max(h, w) > job.max_side:
        rgb, mask, visible, depth, K = downscale(rgb, (mask, visible, depth), K, job.max_side)
    if rec.mask_method:  # made from the undistorted (and downscaled) image, whose camera is K
        mask = capture_mask(rec.mask_method, rgb, K, rec.t, rec.mask_radius_m)
    visible = mask if visible is None else visible
    if rec.crop == "mask":
        h, w = mask.shape
        ys, xs = np.nonzero(mask)
        if len(ys) == 0:
            raise ImageError(f"{rec.image}: the object's mask is empty; nothing to crop around")
        cx, cy = (xs.min() + xs.max() + 1) / 2, (ys.min() + ys.max() + 1) / 2
        half = int(np.ceil(max(xs.max() - xs.min() + 1, ys.max() - ys.min() + 1) * 0.6))
        x0, y0 = int(round(cx)) - half, int(round(cy)) - half
        x1, y1 = x0 + 2 * half, y0 + 2 * half
        pad = max(0, -x0, -y0, x1 - w, y1 - h)  # squares near the border are padded with black
        if pad:
            rgb, mask, visible, depth = (None if a is None else np.pad(a, ((pad, pad), (pad, pad)) +
                                                                       ((0, 0),) * (a.ndim - 2))
                                         for a in (rgb, mask, visible, depth))
        X0, Y0 = x0 + pad, y0 + pad
        tw, th = job.size or (x1 - x0, y1 - y0)
        sx, sy = tw / (x1 - x0), th / (y1 - y0)
        rgb = cv2.resize(rgb[Y0:Y0 + 2 * half, X0:X0 + 2 * half], (tw, th), interpolation=cv2.INTER_AREA)
        mask = cv2.resize(mask[Y0:Y0 + 2 * half, X0:X0 + 2 * half], (tw, th), interpolation=cv2.INTER_NEAREST)
        visible = cv2.resize(visible[Y0:Y0 + 2 * half, X0:X0 + 2 * half], (tw, th),
                             interpolation=cv2.INTER_NEAREST)
        depth = None if depth is None else cv2.resize(depth[Y0:Y0 + 2 * half, X0:X0 + 2 * half], (tw, th),
                                                      interpolation=cv2.INTER_NEAREST)
        # The crop's pixel centres: u' = (u - x0 + 0.5) * sx - 0.5.
        K = np.array([[K[0, 0] * sx, 0, (K[0, 2] - x0 + 0.5) * sx - 0.5],
                      [0, K[1, 1] * sy, (K[1, 2] - y0 + 0.5) * sy - 0.5], [0, 0, 1.0]])
    if not mask.any():  # validate refuses an empty mask: the frame is skipped, listed
        after = " after undistortion" if any(rec.distortion) else ""
        raise ImageError(f"{rec.image}: the object's mask is empty{after}"
                         "; give a mask that covers the object")
    return rgb, mask, depth, K, visible


def _read(rec, job):
    """(rec, (rgb, mask, depth, K, visible)) or (rec, ImageError)."""
    try:
        return rec, _load_frame(rec, job)
    except ImageError as exc:
        return rec, exc


def import_shard(job: ImportJob, report=lambda n: None) -> dict:
    """Read the job's frames (skipping unreadable ones, listed) and write its shard, streamed.
    The writer is sized for every frame; a frame skipped part way (a broken image past its
    header, an empty mask) restarts the shard without it (its progress taken back)."""
    records, skipped = list(job.records), []
    while True:
        done = _stream(job, records, skipped, report)
        if done is not None:
            return done


def _stream(job: ImportJob, records: list, skipped: list, report):
    """The shard of ``records`` (their count fixed); None, with ``records`` and ``skipped``
    updated, when one of them could not be read. A block is compressed (the writer's threads)
    while the next is read, then stored."""
    labels, writer, stored, pending = [], None, 0, None
    visible_field = any(r.visible_mask is not None for r in records)
    depth_field = any(r.depth is not None for r in records)
    try:
        with ThreadPoolExecutor(THREADS) as pool:
            for start in range(0, len(records), BLOCK):
                block = list(pool.map(lambda r: _read(r, job), records[start:start + BLOCK]))
                failed = [(rec, exc) for rec, exc in block if isinstance(exc, ImageError)]
                if failed:
                    skipped += [[rec.image, str(exc)] for rec, exc in failed]
                    records[:] = [r for r in records if all(r is not f for f, _ in failed)]
                    report(len(failed) - stored)  # the skipped counted, what was stored taken back
                    return {"entry": None, "skipped": skipped, "frames": 0} if not records else None
                if writer is None:
                    writer = _writer(job, block, len(records), visible_field, depth_field)
                images = _block_images(job, writer, block, visible_field, depth_field, labels)
                writer.prepare(start, images)
                if pending is not None:
                    stored += _store(writer, pending, report)
                pending = (start, images)
            stored += _store(writer, pending, report)
            target = writer.finish(_label_fields(job, labels), _attrs(job, skipped))
            return {"entry": manifest_entry(target, writer.written), "skipped": skipped, "frames": len(labels)}
    finally:
        if writer is not None:
            writer.__exit__(None, None, None)


def _writer(job: ImportJob, block: list, frames: int, visible_field: bool, depth_field: bool):
    """An open ShardWriter for ``frames`` frames of the size of ``block``'s first."""
    h, w = block[0][1][0].shape[:2]
    images = ("rgb", "mask") + (("depth",) if depth_field else ()) + (("visible_mask",) if visible_field else ())
    return ShardWriter(Path(job.out_dir) / job.name, frames=frames, height=h, width=w, images=images).__enter__()


def _store(writer, pending, report) -> int:
    start, images = pending
    writer.write_images(start, images)
    report(len(images["rgb"]))
    return len(images["rgb"])


def _block_images(job, writer, block, visible_field, depth_field, labels) -> dict:
    """{image field: (k, ...) array} of a block; each frame's labels appended to ``labels``."""
    sizes = {frame[0].shape for _, frame in block} | {(writer.height, writer.width, 3)}
    if len(sizes) > 1:
        raise SpmError(f"{job.name}: images of different sizes {sorted(sizes)} in one shard; pass --size WxH "
                       "(or --max-side for a capture)")
    images = {"rgb": np.stack([f[0] for _, f in block]), "mask": np.stack([f[1] for _, f in block])}
    if depth_field:   # frames of a shard with depth whose own depth image is missing: 0, none measured
        images["depth"] = np.stack([np.zeros(f[1].shape, np.float32) if f[2] is None else f[2] for _, f in block])
    if visible_field:
        images["visible_mask"] = np.stack([f[4] for _, f in block])
    for rec, (_, mask, _, K, visible) in block:
        full = int(mask.sum())
        covered = 1.0 - int(visible.sum()) / full if visible_field and full else 0.0
        labels.append((rec, K, covered))
    return images


def _label_fields(job: ImportJob, labels: list) -> dict:
    recs = [rec for rec, _, _ in labels]
    n = len(recs)
    R = np.array([r.R for r in recs], dtype=np.float64).reshape(n, 3, 3)
    t = np.array([r.t for r in recs], dtype=np.float64).reshape(n, 3)
    return {
        "K": np.stack([K for _, K, _ in labels]), "R": R, "t": t, "pose": pose_to_label(R, t).reshape(n, 6),
        "azimuth": np.array([r.azimuth for r in recs]), "elevation": np.array([r.elevation for r in recs]),
        "roll": np.array([r.roll for r in recs]), "distance": np.array([r.distance for r in recs]),
        "look_at": np.zeros((n, 3)), "path_index": np.array([r.path_index for r in recs], dtype=np.int64),
        "instance_id": np.array([r.instance_id for r in recs], dtype=np.int64),
        "instance_name": [r.instance_name for r in recs], "class_name": [r.class_name for r in recs],
        "source": [job.source] * n, "label_measured": np.array([r.label_measured for r in recs], dtype=bool),
        "occlusion_fraction": np.array([c for _, _, c in labels], np.float32),
        "occlusion_rects": np.zeros((n, 1, 4), np.int32),
        "source_shard": [r.image for r in recs], "source_frame": np.arange(n, dtype=np.int64),
    }


def _attrs(job: ImportJob, skipped: list) -> dict:
    return {**json.loads(job.attrs_json), "plan_key": job.plan_key, "renderer": "none (imported)", "seed": 0,
            "source": job.source, "spm_version": __version__, "import_skipped": json.dumps(skipped)}

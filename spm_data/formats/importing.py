"""What every importer shares: frame records and shards of imported frames (images are read by io/images.py).

An importer lists :class:`FrameRecord` s (one per output frame: where its image
is, its pose, intrinsics, class, and which label components are measured);
:func:`import_records` groups them by image size into shards and writes them
through the resumable shard run. Unreadable images are skipped and listed,
never fatal.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from spm_data import __version__
from spm_data.core.specs import class_name_problem
from spm_data.formats.capture_images import capture_mask, undistort
from spm_data.errors import SpmError
from spm_data.core.poses import (MAX_DISTANCE_M, MAX_FOCAL_PX, ROTATION_TOLERANCE, is_rotation, nearest_rotation,
                                  pose_to_label)
from spm_data.jobs.shard_runs import RunSummary, run_shard_jobs
from spm_data.io.images import ImageError, decode_alpha, decode_image, read_bytes
from spm_data.io.shards import SCHEMA_VERSION, manifest_entry, write_shard

NAN3 = (float("nan"),) * 3


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
    mask_alpha: bool = False           # the mask is ``mask``'s opacity (alpha at least 128 of 255)
    distortion: tuple = ()             # OpenCV's k1, k2, p1, p2[, k3] (or k1..k4 with fisheye): undistorted to K
    fisheye: bool = False              # ``distortion`` is OpenCV's fisheye model (cv2.fisheye)
    mask_method: str = ""              # "none", "sphere", "grabcut": the mask is made (formats/capture_images.py)
    mask_radius_m: float = 0.0         # the sphere's radius (metres, around the object origin) for those


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
    depth = np.zeros((h, w), np.float32)
    if rec.depth is not None:
        d = decode_image(read_bytes(rec.depth), rec.depth, mode="raw")
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
    if rec.mask_method:  # made from the undistorted image, whose camera is K
        mask = capture_mask(rec.mask_method, rgb, K, rec.t, rec.mask_radius_m)
    visible = mask if visible is None else visible
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
    if not mask.any():  # validate refuses an empty mask: the frame is skipped, listed
        raise ImageError(f"{rec.image}: the object's mask is empty{' after undistortion' if any(rec.distortion) else ''}"
                         "; give a mask that covers the object")
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
    non-finite values, R not a rotation (core/poses.ROTATION_TOLERANCE), the camera farther
    than MAX_DISTANCE_M, fx or fy not in (0, MAX_FOCAL_PX], cx or cy beyond it, K's last row
    not (0, 0, 1). Importers call it before writing."""
    R = np.asarray(R, dtype=np.float64).reshape(3, 3)
    t = np.asarray(t, dtype=np.float64).reshape(3)
    fmt = lambda a: "[" + ", ".join(f"{v:g}" for v in np.ravel(a)) + "]"  # noqa: E731
    if not np.isfinite(R).all():
        return f"the rotation has a non-finite value (R = {fmt(R)}); expected finite numbers"
    if not is_rotation(R):
        return (f"R = {fmt(R)} is not a rotation matrix (orthonormal within {ROTATION_TOLERANCE:g}, "
                "determinant +1)")
    if not np.isfinite(t).all():
        return f"the translation has a non-finite value (t = {fmt(t)}); expected finite numbers"
    with np.errstate(over="ignore"):
        distance = float(np.linalg.norm(t))
    if not distance <= MAX_DISTANCE_M:
        return f"the camera is {distance:g} m from the object (t = {fmt(t)}); expected at most {MAX_DISTANCE_M:g} m"
    return None if K is None else intrinsics_problem(K)


def intrinsics_problem(K) -> str | None:
    """Why K (3, 3) cannot be imported (see pose_problem), or None."""
    K = np.asarray(K, dtype=np.float64).reshape(3, 3)
    fmt = lambda a: "[" + ", ".join(f"{v:g}" for v in np.ravel(a)) + "]"  # noqa: E731
    if not np.isfinite(K).all():
        return f"the intrinsics have a non-finite value (K = {fmt(K)}); expected finite fx, fy, cx, cy"
    if not (K[0, 0] > 0 and K[1, 1] > 0):
        return f"focal length fx = {K[0, 0]:g}, fy = {K[1, 1]:g}; expected fx, fy > 0 pixels"
    if max(K[0, 0], K[1, 1], abs(K[0, 2]), abs(K[1, 2])) > MAX_FOCAL_PX or not np.array_equal(K[2], [0, 0, 1]):
        return f"K = {fmt(K)} is not a camera (fx, fy, |cx|, |cy| up to {MAX_FOCAL_PX:g} pixels, last row 0, 0, 1)"
    return None


def check_records(records) -> list:
    """``records`` with each R replaced by the rotation nearest it (stored rotations are exact,
    as validate wants them); SpmError naming the first record whose pose or intrinsics cannot be
    imported (see pose_problem), or whose class name render would refuse (class_name_problem: a
    class names shard files)."""
    named, checked = set(), []
    for rec in records:
        problem = pose_problem(rec.R, rec.t, rec.K)
        if problem is not None:
            raise SpmError(f"{rec.image}: {problem}; correct its pose or intrinsics (nothing was written)")
        if rec.class_name not in named:
            problem = class_name_problem(rec.class_name)
            if problem is not None:
                raise SpmError(f"{rec.image}: class {problem}; give another class name (nothing was written)")
            named.add(rec.class_name)
        checked.append(replace(rec, R=tuple(nearest_rotation(rec.R).ravel())))
    return checked


def import_records(records, out_dir, *, source: str, prefix: str, frames_per_shard=256, threshold=10,
                   size=None, attrs=None, progress=None, executor=None, problems=()) -> RunSummary:
    """Write ``records`` as shards ``PREFIX-NNNNN.h5`` in ``out_dir`` (resuming). ``problems``:
    (what, why) the importer skipped while planning, named when no frame is left to import.
    SpmError when nothing can be imported: no records, or every frame skipped as it was read."""
    if not records:
        raise SpmError(f"nothing to import: no frames were found{_first_problems(problems)}")
    records = check_records(records)  # every pose before the first shard: a bad one writes nothing
    attrs_json = json.dumps(attrs or {}, sort_keys=True)
    key_base = json.dumps([SCHEMA_VERSION, source, threshold, size, attrs_json], sort_keys=True)
    jobs = []
    for i, start in enumerate(range(0, len(records), frames_per_shard)):
        chunk = tuple(records[start:start + frames_per_shard])
        key = hashlib.sha256((key_base + repr(chunk)).encode()).hexdigest()
        jobs.append(ImportJob(f"{prefix}-{i:05d}.h5", key, str(out_dir), chunk, source, threshold,
                              tuple(size) if size else None, attrs_json))
    summary = run_shard_jobs(import_shard, jobs, out_dir, executor=executor, progress=progress, verb="imported")
    if summary.frames == 0 and not (summary.interrupted or summary.failed or summary.skipped):
        skipped = [tuple(s) for r in summary.results.values() for s in r.get("skipped", [])] + list(problems)
        raise SpmError(f"nothing imported: every one of {len(records)} frames was skipped"
                       f"{_first_problems(skipped)}; nothing was written")
    return summary


def _first_problems(problems) -> str:
    """" (N skipped; first: WHAT: WHY; ...)" of (what, why) pairs, the first three; "" when none."""
    if not problems:
        return ""
    first = "; ".join(f"{what}: {str(why).removeprefix(f'{what}: ')}" for what, why in list(problems)[:3])
    return f" ({len(problems)} skipped; first: {first})"


def import_report(summary: RunSummary, problems=()) -> str:
    """The summary plus every skipped frame and why (listing problems found while planning too)."""
    skipped = [tuple(s) for r in summary.results.values() for s in r.get("skipped", [])] + list(problems)
    details = [f"  skipped {len(skipped)} images:"] + [f"    {name}: {why}" for name, why in skipped[:50]]
    if len(skipped) > 50:
        details.append(f"    ... and {len(skipped) - 50} more")
    return summary.report(details if skipped else ["  skipped 0 images"])

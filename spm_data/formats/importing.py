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
from dataclasses import dataclass, replace

import numpy as np

from spm_data.core.specs import class_name_problem
from spm_data.errors import SpmError
from spm_data.formats.import_frames import ImportJob, import_shard, threshold_mask  # noqa: F401 (re-exported)
from spm_data.core.poses import MAX_DISTANCE_M, MAX_FOCAL_PX, ROTATION_TOLERANCE, is_rotation, nearest_rotation
from spm_data.jobs.shard_runs import RunSummary, run_shard_jobs
from spm_data.io.shards import SCHEMA_VERSION

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
                   size=None, attrs=None, progress=None, executor=None, problems=(), max_side=None) -> RunSummary:
    """Write ``records`` as shards ``PREFIX-NNNNN.h5`` in ``out_dir`` (resuming); frames whose longer
    side is over ``max_side`` are downscaled to it (K with them). ``problems``:
    (what, why) the importer skipped while planning, named when no frame is left to import.
    SpmError when nothing can be imported: no records, or every frame skipped as it was read."""
    if not records:
        raise SpmError(f"nothing to import: no frames were found{_first_problems(problems)}")
    records = check_records(records)  # every pose before the first shard: a bad one writes nothing
    attrs_json = json.dumps(attrs or {}, sort_keys=True)
    key_base = json.dumps([SCHEMA_VERSION, source, threshold, size, attrs_json] + ([max_side] if max_side else []),
                          sort_keys=True)
    jobs = []
    for i, start in enumerate(range(0, len(records), frames_per_shard)):
        chunk = tuple(records[start:start + frames_per_shard])
        key = hashlib.sha256((key_base + repr(chunk)).encode()).hexdigest()
        jobs.append(ImportJob(f"{prefix}-{i:05d}.h5", key, str(out_dir), chunk, source, threshold,
                              tuple(size) if size else None, attrs_json, int(max_side or 0)))
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

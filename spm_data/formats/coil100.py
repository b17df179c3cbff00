"""COIL-100 and COIL-20 (Nayar et al., Columbia, 1996) -> shards. See docs/datasets.md for what is
measured and assumed.

COIL-100: the extracted folder, ``coil-100.zip`` (``obj{1..100}__{angle}.png``, angle
0, 5, ..., 355) or ``coil-100.tar.gz`` (the same names as ``.ppm``, reportedly 16-bit).
COIL-20: the extracted folder or zip of ``coil-20-proc`` / ``coil-20-unproc``
(``obj{1..20}__{view}.png``, view 0..71, five degrees apart). Both are turntables shot
the same way: only the rotation about the vertical axis is measured, as the path's
azimuth; elevation and distance are fixed but unpublished, so the label uses
``--elevation`` and ``--distance`` and flags those parts as assumed. Images may be any
size, grey or colour (grey becomes RGB); K is made from each image's own size and the
assumed ``--fov``.
"""

from __future__ import annotations

import csv
import re
import tarfile
import zipfile
from pathlib import Path

from spm_data.errors import SpmError
from spm_data.formats.importing import FrameRecord, check_fov_option, import_records
from spm_data.core.poses import camera_pose, intrinsics_from_fov
from spm_data.io.images import ImageError, image_sizes

NAME = re.compile(r"(?:^|/)obj(\d+)__(\d+)\.(png|ppm)$", re.IGNORECASE)
ANGLES = tuple(range(0, 360, 5))
# How each layout numbers its views: COIL-100 by the turntable angle, COIL-20 by the view's index.
LAYOUTS = {"coil100": {"name": "COIL-100", "number": "angle", "pattern": "objN__ANGLE.png/.ppm"},
           "coil20": {"name": "COIL-20", "number": "view", "pattern": "objN__VIEW.png (VIEW 0..71)"}}
# rx (= 90 + elevation) and ry (roll) come from the assumed elevation, rz from the
# measured turntable angle, t from the assumed distance: only rz is measured.
MAX_DIGITS = 9  # an object number must fit the shards' int64 instance ids
MEASURED = (False, False, True, False, False, False)


def list_members(path) -> list[str]:
    """Image references of a COIL-100 folder, zip or tar archive, and everything else in it."""
    path = Path(path)
    if path.is_dir():
        return sorted(str(p) for p in path.rglob("*") if p.is_file())
    if not path.is_file():
        raise SpmError(f"no COIL images at {path}: give the extracted folder or the archive")
    if zipfile.is_zipfile(path):
        with zipfile.ZipFile(path) as zf:
            return sorted(f"zip:{path}::{n}" for n in zf.namelist() if not n.endswith("/"))
    try:
        with tarfile.open(path) as tf:
            return sorted(f"tar:{path}::{m.name}" for m in tf.getmembers() if m.isfile())
    except tarfile.TarError:
        raise SpmError(f"{path}: neither a folder, a zip nor a tar archive") from None


def read_class_map(path) -> dict[int, str]:
    """``object id -> class name`` from a UTF-8 CSV with columns ``object,class`` (a header is
    optional); SpmError for a file that is not such a text, or that gives one id twice."""
    mapping, lines = {}, {}
    try:
        with open(path, newline="", encoding="utf-8") as fh:
            for line, row in enumerate(csv.reader(fh), 1):
                if not row or row[0].strip().lower() in ("object", "obj", "id", "object_id"):
                    continue
                if len(row) < 2:
                    raise SpmError(f"{path}:{line}: expected 'object,class' rows, got {row}")
                try:
                    obj = int(row[0].strip().removeprefix("obj"))
                except ValueError:
                    raise SpmError(f"{path}:{line}: object id {row[0]!r} is not a number") from None
                if obj in mapping:
                    raise SpmError(f"{path}:{line}: object {obj} is given a class twice (lines {lines[obj]} and "
                                   f"{line}); keep one row per object")
                mapping[obj], lines[obj] = row[1].strip(), line
    except OSError as exc:
        raise SpmError(f"cannot read class map {path}: {exc.strerror or exc}") from None
    except (UnicodeDecodeError, csv.Error):
        raise SpmError(f"{path}: not a text CSV of 'object,class' rows (UTF-8); give the class map as text") \
            from None
    return mapping


def check_assumed_camera(elevation, distance, fov) -> None:
    """SpmError unless --elevation is in [-90, 90] degrees, --distance > 0 metres, --fov in (0, 180) degrees."""
    if not -90 <= elevation <= 90:  # NaN fails every comparison
        raise SpmError(f"--elevation {elevation}: expected a finite angle in [-90, 90] degrees")
    if not 0 < distance < float("inf"):
        raise SpmError(f"--distance {distance}: expected a finite camera distance > 0 metres")
    check_fov_option(fov)


def _angle(number: int, layout: str) -> int | None:
    """The turntable angle (degrees) of a file's number in ``layout``; None when it names no view."""
    if LAYOUTS[layout]["number"] == "angle":
        return number if number in ANGLES else None
    return 5 * number if 0 <= number < len(ANGLES) else None


def _intrinsics(size, fov: float, known: dict):
    """K (3, 3) as a tuple of an image of ``size`` (width, height) and the vertical ``fov``; the
    ImageError of an image whose header could not be read is raised. ``known``: K per size."""
    if isinstance(size, ImageError):
        raise size
    if size not in known:
        known[size] = tuple(intrinsics_from_fov(fov, *size).ravel())
    return known[size]


def coil_records(path, *, layout="coil100", elevation=0.0, distance=1.0, fov=30.0, classes=None):
    """(records, problems) of a COIL-100 (``layout`` "coil100") or COIL-20 ("coil20") set: one
    record per view found, K from each image's size; problems lists foreign files, numbers that
    name no view, missing views and images whose header cannot be read. The assumed camera
    (``elevation``, ``distance``, ``fov``) is checked first: SpmError naming the option."""
    check_assumed_camera(elevation, distance, fov)
    refs = list_members(path)
    found: dict[int, dict[int, str]] = {}
    problems = []
    what = LAYOUTS[layout]
    numbers = []
    for ref in refs:
        m = NAME.search(ref.split("::")[-1])
        if not m:
            problems.append((ref, f"foreign file (not {what['pattern']})"))
            continue
        if max(len(m.group(1)), len(m.group(2))) > MAX_DIGITS:
            problems.append((ref, f"object or view number has over {MAX_DIGITS} digits; not a COIL file name"))
            continue
        numbers.append(int(m.group(2)))
        obj, angle = int(m.group(1)), _angle(int(m.group(2)), layout)
        if angle is None:
            expected = "a multiple of 5 in 0..355" if what["number"] == "angle" else "a view number in 0..71"
            problems.append((ref, f"{what['number']} {int(m.group(2))} is not {expected}"))
            continue
        if angle in found.setdefault(obj, {}):
            problems.append((ref, f"the same view as {found[obj][angle]} (kept)"))
            continue
        found[obj][angle] = ref
    if layout == "coil100" and numbers and max(numbers) < len(ANGLES) and any(n % 5 for n in numbers):
        raise SpmError(f"{path}: the files are numbered by view (0..71), not by angle: this is the COIL-20 "
                       "layout; use spm-data import coil20")
    if layout == "coil20" and numbers and max(numbers) >= len(ANGLES) and not any(n % 5 for n in numbers):
        raise SpmError(f"{path}: the files are numbered by angle (0..355), not by view: this is the COIL-100 "
                       "layout; use spm-data import coil100")
    records, known = [], {}
    sizes = image_sizes([ref for views in found.values() for ref in views.values()])
    for obj in sorted(found):
        missing = [a for a in ANGLES if a not in found[obj]]
        problems += [(f"obj{obj}__{a if what['number'] == 'angle' else a // 5}", "missing view") for a in missing]
        for angle in (a for a in ANGLES if a in found[obj]):
            try:
                K = _intrinsics(sizes[found[obj][angle]], fov, known)
            except ImageError as exc:
                problems.append((found[obj][angle], str(exc).removeprefix(found[obj][angle] + ": ")))
                continue
            R, t = camera_pose(angle, elevation, 0.0, distance)
            records.append(FrameRecord(
                image=found[obj][angle], class_name=(classes or {}).get(obj, f"{layout}-obj{obj}"),
                instance_name=f"{layout}-obj{obj}", instance_id=obj, R=tuple(R.ravel()), t=tuple(t),
                K=K, label_measured=MEASURED, azimuth=float(angle), elevation=float(elevation), roll=0.0,
                distance=float(distance), path_index=angle // 5))
    return records, problems


def coil100_records(path, *, elevation=0.0, distance=1.0, fov=30.0, classes=None):
    """coil_records of a COIL-100 set."""
    return coil_records(path, layout="coil100", elevation=elevation, distance=distance, fov=fov, classes=classes)


def _import(layout, path, out_dir, *, elevation, distance, fov, classes_csv, threshold, frames_per_shard,
            progress, executor):
    classes = read_class_map(classes_csv) if classes_csv else None
    records, problems = coil_records(path, layout=layout, elevation=elevation, distance=distance, fov=fov,
                                     classes=classes)
    attrs = {"import": layout, "assumed_elevation": elevation, "assumed_distance": distance,
             "assumed_fov": fov, "mask_source": f"threshold: brightest channel > {threshold}"}
    summary = import_records(records, out_dir, source=layout, prefix=layout, threshold=threshold,
                             frames_per_shard=frames_per_shard, attrs=attrs, progress=progress, executor=executor,
                             problems=problems)
    return summary, problems


def import_coil100(path, out_dir, *, elevation=0.0, distance=1.0, fov=30.0, classes_csv=None, threshold=10,
                   frames_per_shard=256, progress=None, executor=None):
    """Import COIL-100 into ``out_dir``; returns (RunSummary, problems)."""
    return _import("coil100", path, out_dir, elevation=elevation, distance=distance, fov=fov,
                   classes_csv=classes_csv, threshold=threshold, frames_per_shard=frames_per_shard,
                   progress=progress, executor=executor)


def import_coil20(path, out_dir, *, elevation=0.0, distance=1.0, fov=30.0, classes_csv=None, threshold=10,
                  frames_per_shard=256, progress=None, executor=None):
    """Import COIL-20 (views numbered 0..71) into ``out_dir``; returns (RunSummary, problems)."""
    return _import("coil20", path, out_dir, elevation=elevation, distance=distance, fov=fov,
                   classes_csv=classes_csv, threshold=threshold, frames_per_shard=frames_per_shard,
                   progress=progress, executor=executor)

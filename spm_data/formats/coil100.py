"""COIL-100 (Nayar et al. 1996) -> shards. See docs/datasets.md for what is measured and assumed.

Accepted: the extracted folder, ``coil-100.zip`` (``obj{1..100}__{angle}.png``,
128 x 128 RGB), or ``coil-100.tar.gz`` (the same names as ``.ppm``, reportedly
16-bit). A turntable: only the rotation about the vertical axis is measured, as
the path's azimuth; elevation and distance are fixed but unpublished, so the
label uses ``--elevation`` and ``--distance`` and flags those parts as assumed.
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

NAME = re.compile(r"(?:^|/)obj(\d+)__(\d+)\.(png|ppm)$", re.IGNORECASE)
ANGLES = tuple(range(0, 360, 5))
# rx (= 90 + elevation) and ry (roll) come from the assumed elevation, rz from the
# measured turntable angle, t from the assumed distance: only rz is measured.
MEASURED = (False, False, True, False, False, False)


def list_members(path) -> list[str]:
    """Image references of a COIL-100 folder, zip or tar archive, and everything else in it."""
    path = Path(path)
    if path.is_dir():
        return sorted(str(p) for p in path.rglob("*") if p.is_file())
    if not path.is_file():
        raise SpmError(f"COIL-100 not found at {path}")
    if zipfile.is_zipfile(path):
        with zipfile.ZipFile(path) as zf:
            return sorted(f"zip:{path}::{n}" for n in zf.namelist() if not n.endswith("/"))
    try:
        with tarfile.open(path) as tf:
            return sorted(f"tar:{path}::{m.name}" for m in tf.getmembers() if m.isfile())
    except tarfile.TarError:
        raise SpmError(f"{path}: neither a folder, a zip nor a tar archive") from None


def read_class_map(path) -> dict[int, str]:
    """``object id -> class name`` from a CSV with columns ``object,class`` (a header is optional)."""
    mapping = {}
    try:
        with open(path, newline="") as fh:
            for row in csv.reader(fh):
                if not row or row[0].strip().lower() in ("object", "obj", "id", "object_id"):
                    continue
                if len(row) < 2:
                    raise SpmError(f"{path}: expected 'object,class' rows, got {row}")
                try:
                    mapping[int(row[0].strip().removeprefix("obj"))] = row[1].strip()
                except ValueError:
                    raise SpmError(f"{path}: object id {row[0]!r} is not a number") from None
    except OSError as exc:
        raise SpmError(f"cannot read class map {path}: {exc.strerror}") from None
    return mapping


def check_assumed_camera(elevation, distance, fov) -> None:
    """SpmError unless --elevation is in [-90, 90] degrees, --distance > 0 metres, --fov in (0, 180) degrees."""
    if not -90 <= elevation <= 90:  # NaN fails every comparison
        raise SpmError(f"--elevation {elevation}: expected a finite angle in [-90, 90] degrees")
    if not 0 < distance < float("inf"):
        raise SpmError(f"--distance {distance}: expected a finite camera distance > 0 metres")
    check_fov_option(fov)


def coil100_records(path, *, elevation=0.0, distance=1.0, fov=30.0, classes=None):
    """(records, problems): one record per view found; problems lists foreign files and missing views.
    The assumed camera (``elevation``, ``distance``, ``fov``) is checked first: SpmError naming the option."""
    check_assumed_camera(elevation, distance, fov)
    refs = list_members(path)
    K = tuple(intrinsics_from_fov(fov, 128, 128).ravel())
    found: dict[int, dict[int, str]] = {}
    problems = []
    for ref in refs:
        m = NAME.search(ref.split("::")[-1])
        if not m:
            problems.append((ref, "foreign file (not objN__ANGLE.png/.ppm)"))
            continue
        obj, angle = int(m.group(1)), int(m.group(2))
        if angle not in ANGLES:
            problems.append((ref, f"angle {angle} is not a multiple of 5 in 0..355"))
            continue
        found.setdefault(obj, {})[angle] = ref
    records = []
    for obj in sorted(found):
        missing = [a for a in ANGLES if a not in found[obj]]
        problems += [(f"obj{obj}__{a}", "missing view") for a in missing]
        for angle in (a for a in ANGLES if a in found[obj]):
            R, t = camera_pose(angle, elevation, 0.0, distance)
            records.append(FrameRecord(
                image=found[obj][angle], class_name=(classes or {}).get(obj, f"coil100-obj{obj}"),
                instance_name=f"coil100-obj{obj}", instance_id=obj, R=tuple(R.ravel()), t=tuple(t),
                K=K, label_measured=MEASURED, azimuth=float(angle), elevation=float(elevation), roll=0.0,
                distance=float(distance), path_index=angle // 5))
    return records, problems


def import_coil100(path, out_dir, *, elevation=0.0, distance=1.0, fov=30.0, classes_csv=None, threshold=10,
                   frames_per_shard=256, progress=None, executor=None):
    """Import COIL-100 into ``out_dir``; returns (RunSummary, problems)."""
    classes = read_class_map(classes_csv) if classes_csv else None
    records, problems = coil100_records(path, elevation=elevation, distance=distance, fov=fov, classes=classes)
    attrs = {"import": "coil100", "assumed_elevation": elevation, "assumed_distance": distance,
             "assumed_fov": fov, "mask_source": f"threshold: brightest channel > {threshold}"}
    summary = import_records(records, out_dir, source="coil100", prefix="coil100", threshold=threshold,
                             frames_per_shard=frames_per_shard, attrs=attrs, progress=progress, executor=executor)
    return summary, problems

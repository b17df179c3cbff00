"""A folder of images plus one CSV of per-image poses -> shards; and the assumed CVL layout.

poses.csv columns (header required; see docs/datasets.md):
  image                        path relative to the CSV's folder
  r11 .. r33 | qw qx qy qz | rx ry rz    rotation object -> OpenCV camera: a matrix,
                               a quaternion (scalar first), or Euler angles in degrees
                               in the order given by --euler (scipy's notation, default XYZ)
  tx ty tz                     translation object -> camera, in --unit (m, cm or mm)
  fx fy cx cy (optional)       intrinsics in pixels; else --fov
  mask, depth (optional)       a mask image; a uint16 depth image in --depth-unit
  class, instance (optional)   else --class and the image's folder name
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from spm_data.errors import SpmError
from spm_data.importing import FrameRecord, image_size, import_records, ImageError

UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001}
MATRIX = [f"r{i}{j}" for i in (1, 2, 3) for j in (1, 2, 3)]


def _float(row, key, where):
    try:
        return float(row[key])
    except (TypeError, ValueError):
        raise SpmError(f"{where}: column {key!r} is not a number ({row.get(key)!r})") from None


def rotation_from_row(row: dict, euler: str, where: str) -> np.ndarray:
    """(3, 3) rotation from a CSV row: matrix, quaternion (w first) or Euler degrees."""
    if all(k in row for k in MATRIX):
        R = np.array([_float(row, k, where) for k in MATRIX]).reshape(3, 3)
        if not np.allclose(R @ R.T, np.eye(3), atol=1e-4) or np.linalg.det(R) < 0:
            raise SpmError(f"{where}: r11..r33 is not a rotation matrix")
        return R
    if all(k in row for k in ("qw", "qx", "qy", "qz")):
        q = np.array([_float(row, k, where) for k in ("qx", "qy", "qz", "qw")])
        if not np.isclose(np.linalg.norm(q), 1.0, atol=1e-3):
            raise SpmError(f"{where}: quaternion is not unit length ({np.linalg.norm(q):.4f})")
        return Rotation.from_quat(q).as_matrix()
    if all(k in row for k in ("rx", "ry", "rz")):
        try:
            return Rotation.from_euler(euler, [_float(row, k, where) for k in ("rx", "ry", "rz")],
                                       degrees=True).as_matrix()
        except ValueError as exc:
            raise SpmError(f"--euler {euler!r}: {exc}") from None
    raise SpmError(f"{where}: no rotation: give r11..r33, qw qx qy qz, or rx ry rz columns")


def folder_records(poses_csv, *, unit="m", euler="XYZ", fov=None, class_name="folder", depth_unit="mm",
                   id_offset=0, base=None):
    """(records, problems) for one poses CSV; problems lists images that are missing or unreadable."""
    poses_csv = Path(poses_csv)
    if unit not in UNITS or depth_unit not in UNITS:
        raise SpmError(f"--unit and --depth-unit take one of {', '.join(UNITS)}; got {unit!r}, {depth_unit!r}")
    try:
        with open(poses_csv, newline="") as fh:
            rows = list(csv.DictReader(fh))
    except OSError as exc:
        raise SpmError(f"cannot read poses table {poses_csv}: {exc.strerror}") from None
    if not rows:
        raise SpmError(f"{poses_csv}: no rows")
    if "image" not in rows[0]:
        raise SpmError(f"{poses_csv}: no 'image' column (columns: {', '.join(rows[0])})")
    base = Path(base) if base is not None else poses_csv.parent
    records, problems, instances = [], [], {}
    for n, row in enumerate(rows, start=2):
        where = f"{poses_csv}:{n}"
        image = base / row["image"]
        if not image.is_file():
            problems.append((str(image), "missing image listed in the poses table"))
            continue
        R = rotation_from_row(row, euler, where)
        t = np.array([_float(row, k, where) for k in ("tx", "ty", "tz")]) * UNITS[unit]
        try:
            w, h = image_size(str(image))
        except ImageError as exc:
            problems.append((str(image), str(exc)))
            continue
        if all(row.get(k) not in (None, "") for k in ("fx", "fy", "cx", "cy")):
            K = np.array([[_float(row, "fx", where), 0, _float(row, "cx", where)],
                          [0, _float(row, "fy", where), _float(row, "cy", where)], [0, 0, 1.0]])
        elif fov is not None:
            from spm_data.poses import intrinsics_from_fov

            K = intrinsics_from_fov(fov, w, h)
        else:
            raise SpmError(f"{where}: no intrinsics: add fx fy cx cy columns or pass --fov")
        instance = row.get("instance") or image.parent.name
        instances.setdefault(instance, len(instances) + id_offset)
        mask = row.get("mask") or None
        depth = row.get("depth") or None
        records.append(FrameRecord(
            image=str(image), class_name=row.get("class") or class_name, instance_name=instance,
            instance_id=instances[instance], R=tuple(R.ravel()), t=tuple(t), K=tuple(K.ravel()),
            mask=str(base / mask) if mask else None, depth=str(base / depth) if depth else None,
            depth_scale_m=UNITS[depth_unit], path_index=n - 2, distance=float(np.linalg.norm(t))))
    return records, problems


def import_folder(folder, out_dir, *, poses_csv=None, unit="m", euler="XYZ", fov=None, class_name="folder",
                  depth_unit="mm", threshold=10, source="folder", prefix=None, frames_per_shard=256, workers=1,
                  progress=None, executor=None):
    """Import ``folder``'s images listed in ``poses_csv`` (default FOLDER/poses.csv; image paths
    are relative to FOLDER)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise SpmError(f"no such folder: {folder}")
    poses_csv = Path(poses_csv) if poses_csv else folder / "poses.csv"
    records, problems = folder_records(poses_csv, unit=unit, euler=euler, fov=fov, class_name=class_name,
                                       depth_unit=depth_unit, base=folder)
    summary = import_records(records, out_dir, source=source, prefix=prefix or source, threshold=threshold,
                             frames_per_shard=frames_per_shard, workers=workers, progress=progress, executor=executor,
                             attrs={"import": source, "poses": str(poses_csv), "unit": unit, "euler": euler})
    return summary, problems


def import_cvl(path, out_dir, *, unit="mm", euler="XYZ", fov=None, threshold=10, frames_per_shard=256,
               workers=1, progress=None, executor=None):
    """The assumed CVL layout: ``PATH/<object>/poses.csv`` beside that object's images
    (docs/datasets.md). The object folder names the class unless the CSV has a class column."""
    path = Path(path)
    tables = sorted(path.glob("*/poses.csv")) if path.is_dir() else []
    if not tables:
        raise SpmError(f"{path}: no <object>/poses.csv found; CVL is read in the layout docs/datasets.md "
                       "describes, or import any layout with: spm-data import folder DIR --poses poses.csv")
    records, problems = [], []
    for table in tables:
        r, p = folder_records(table, unit=unit, euler=euler, fov=fov, class_name=table.parent.name,
                              id_offset=len({x.instance_name for x in records}))
        records += r
        problems += p
    summary = import_records(records, out_dir, source="cvl", prefix="cvl", threshold=threshold,
                             frames_per_shard=frames_per_shard, workers=workers, progress=progress, executor=executor,
                             attrs={"import": "cvl", "unit": unit, "euler": euler})
    return summary, problems

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

Every row is checked before anything is written: required columns, finite numbers,
a rotation, fx, fy > 0 (SpmError "poses.csv:LINE (IMAGE): ..."). Missing or unreadable
images are skipped and listed, as everywhere.
"""

from __future__ import annotations

import csv
from dataclasses import replace
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from spm_data.errors import SpmError
from spm_data.formats.capture_images import made_masks, mask_source
from spm_data.formats.importing import FrameRecord, check_fov_option, import_records
from spm_data.io.images import ImageError, image_size
from spm_data.core.poses import ROTATION_TOLERANCE, is_rotation

UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001}
MATRIX = [f"r{i}{j}" for i in (1, 2, 3) for j in (1, 2, 3)]


QUATERNION = ["qw", "qx", "qy", "qz"]
EULER = ["rx", "ry", "rz"]
TRANSLATION = ["tx", "ty", "tz"]
INTRINSICS = ["fx", "fy", "cx", "cy"]


def _float(row, key, where):
    """A finite number from ``row[key]``; SpmError naming the row and column otherwise."""
    text = row.get(key)
    if text is None or not str(text).strip():
        raise SpmError(f"{where}: column {key!r} is empty; expected a finite number, fix that row")
    try:
        value = float(text)
    except (TypeError, ValueError):
        raise SpmError(f"{where}: column {key!r} is not a number ({text!r}); fix that row") from None
    if not np.isfinite(value):
        raise SpmError(f"{where}: column {key!r} is {str(text).strip()!r}, not a finite number; fix that row")
    return value


def rotation_from_row(row: dict, euler: str, where: str) -> np.ndarray:
    """(3, 3) rotation from a CSV row: matrix, quaternion (w first) or Euler degrees."""
    if all(k in row for k in MATRIX):
        R = np.array([_float(row, k, where) for k in MATRIX]).reshape(3, 3)
        if not is_rotation(R):
            raise SpmError(f"{where}: r11..r33 is not a rotation matrix (orthonormal within {ROTATION_TOLERANCE:g}, "
                           "determinant +1); fix that row")
        return R
    if all(k in row for k in QUATERNION):
        q = np.array([_float(row, k, where) for k in ("qx", "qy", "qz", "qw")])
        if not np.isclose(np.linalg.norm(q), 1.0, atol=1e-3):
            raise SpmError(f"{where}: quaternion is not unit length ({np.linalg.norm(q):.4f}); fix that row")
        return Rotation.from_quat(q).as_matrix()
    if all(k in row for k in EULER):
        angles = [_float(row, k, where) for k in EULER]
        try:
            return Rotation.from_euler(euler, angles, degrees=True).as_matrix()
        except ValueError as exc:
            raise SpmError(f"--euler {euler!r}: {exc}") from None
    raise SpmError(f"{where}: no rotation: give r11..r33, qw qx qy qz, or rx ry rz columns")


def check_columns(poses_csv, fields, fov) -> None:
    """SpmError for a pose table without the columns every row needs (before any row is read)."""
    head = f"{poses_csv}:1: the header has"
    listed = f"(columns: {', '.join(fields)})"
    if "image" not in fields:
        raise SpmError(f"{head} no 'image' column {listed}; add one naming each row's image file")
    sets = (MATRIX, QUATERNION, EULER)
    if not any(all(k in fields for k in keys) for keys in sets):
        partial = [keys for keys in sets if any(k in fields for k in keys)]
        if not partial:
            raise SpmError(f"{head} no rotation {listed}: give r11..r33, qw qx qy qz, or rx ry rz columns")
        missing = [k for k in partial[0] if k not in fields]
        raise SpmError(f"{head} no {', '.join(map(repr, missing))} column {listed}; a rotation needs all of "
                       f"{' '.join(partial[0])}")
    missing = [k for k in TRANSLATION if k not in fields]
    if missing:
        raise SpmError(f"{head} no {', '.join(map(repr, missing))} column {listed}; the translation needs "
                       "tx ty tz (in --unit)")
    given = [k for k in INTRINSICS if k in fields]
    if given and len(given) < len(INTRINSICS):
        missing = [k for k in INTRINSICS if k not in fields]
        raise SpmError(f"{head} no {', '.join(map(repr, missing))} column {listed}; give all of fx fy cx cy, "
                       "or none of them and --fov")
    if not given and fov is None:
        raise SpmError(f"{head} no intrinsics {listed}: add fx fy cx cy columns or pass --fov")


def _intrinsics(row, where) -> np.ndarray | None:
    """K (3, 3) from the row's fx fy cx cy (finite; fx, fy > 0), or None when all four are empty."""
    if all(not (row.get(k) or "").strip() for k in INTRINSICS):
        return None
    fx, fy, cx, cy = (_float(row, k, where) for k in INTRINSICS)
    for name, value in (("fx", fx), ("fy", fy)):
        if value <= 0:
            raise SpmError(f"{where}: column {name!r} is {row[name].strip()!r}; expected a focal length > 0 "
                           "pixels, fix that row")
    return np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]])


def _where(poses_csv, line, row) -> str:
    """"poses.csv:LINE (IMAGE)": a row in messages (1-based line in the file, and its image)."""
    image = (row.get("image") or "").strip()
    return f"{poses_csv}:{line} ({image})" if image else f"{poses_csv}:{line}"


def _read_table(poses_csv, fov):
    """[(line, row)] of a pose table (line: the row's last 1-based line in the file), its columns checked."""
    try:
        with open(poses_csv, newline="", encoding="utf-8-sig") as fh:
            reader = csv.DictReader(fh)
            fields = [f.strip() for f in (reader.fieldnames or [])]
            if not fields:
                raise SpmError(f"{poses_csv}: empty file; expected a header row (image, rotation, tx ty tz, ...)")
            reader.fieldnames = fields
            check_columns(poses_csv, fields, fov)
            rows = []
            for row in reader:
                if None in row or None in row.values():  # more, or fewer, fields than the header
                    got = len(fields) + len(row.get(None) or []) - sum(v is None for v in row.values())
                    raise SpmError(f"{_where(poses_csv, reader.line_num, row)}: {got} fields, the header has "
                                   f"{len(fields)}; fix that row")
                rows.append((reader.line_num, row))
    except OSError as exc:
        raise SpmError(f"cannot read poses table {poses_csv}: {exc.strerror}") from None
    except UnicodeDecodeError as exc:
        raise SpmError(f"{poses_csv}: not UTF-8 text (byte {exc.start}); save the table as a UTF-8 CSV") from None
    except csv.Error as exc:
        raise SpmError(f"{poses_csv}: not a readable CSV ({exc}); save the table as a plain CSV") from None
    if not rows:
        raise SpmError(f"{poses_csv}: no rows")
    return rows


def folder_records(poses_csv, *, unit="m", euler="XYZ", fov=None, class_name="folder", depth_unit="mm",
                   id_offset=0, base=None):
    """(records, problems) for one poses CSV; problems lists images that are missing or unreadable.
    Every row's pose and intrinsics are checked (finite, a rotation, fx, fy > 0): SpmError
    naming the file, line and image for the first bad one, before anything is written."""
    poses_csv = Path(poses_csv)
    if unit not in UNITS or depth_unit not in UNITS:
        raise SpmError(f"--unit and --depth-unit take one of {', '.join(UNITS)}; got {unit!r}, {depth_unit!r}")
    if fov is not None:
        check_fov_option(fov)
    rows = _read_table(poses_csv, fov)
    base = Path(base) if base is not None else poses_csv.parent
    records, problems, instances = [], [], {}
    for index, (line, row) in enumerate(rows):
        where = _where(poses_csv, line, row)
        if not row["image"].strip():
            raise SpmError(f"{where}: column 'image' is empty; name the row's image file, fix that row")
        image = base / row["image"]
        R = rotation_from_row(row, euler, where)
        t = np.array([_float(row, k, where) for k in TRANSLATION]) * UNITS[unit]
        K = _intrinsics(row, where)
        if K is None and fov is None:
            raise SpmError(f"{where}: no intrinsics: fill fx fy cx cy in that row or pass --fov")
        if not image.exists() and not image.is_symlink():   # a FIFO or a folder: said by image_size below
            problems.append((str(image), "missing image listed in the poses table"))
            continue
        try:
            w, h = image_size(str(image))
        except ImageError as exc:
            problems.append((str(image), str(exc)))
            continue
        if K is None:
            from spm_data.core.poses import intrinsics_from_fov

            K = intrinsics_from_fov(fov, w, h)
        instance = row.get("instance") or image.parent.name
        instances.setdefault(instance, len(instances) + id_offset)
        mask = row.get("mask") or None
        depth = row.get("depth") or None
        records.append(FrameRecord(
            image=str(image), class_name=row.get("class") or class_name, instance_name=instance,
            instance_id=instances[instance], R=tuple(R.ravel()), t=tuple(t), K=tuple(K.ravel()),
            mask=str(base / mask) if mask else None, depth=str(base / depth) if depth else None,
            depth_scale_m=UNITS[depth_unit], path_index=index, distance=float(np.linalg.norm(t))))
    return records, problems


def import_folder(folder, out_dir, *, poses_csv=None, unit="m", euler="XYZ", fov=None, class_name="folder",
                  depth_unit="mm", threshold=10, source="folder", prefix=None, frames_per_shard=256,
                  mask=None, radius=None, progress=None, executor=None):
    """Import ``folder``'s images listed in ``poses_csv`` (default FOLDER/poses.csv; image paths
    are relative to FOLDER). ``mask``: one of capture_images.MASK_METHODS, every frame's mask made
    so (``radius``: the sphere's, in ``unit``, around the object origin)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise SpmError(f"no such folder: {folder}")
    made = made_masks(mask, radius, UNITS.get(unit, 1.0), f"--unit ({unit})")
    poses_csv = Path(poses_csv) if poses_csv else folder / "poses.csv"
    records, problems = folder_records(poses_csv, unit=unit, euler=euler, fov=fov, class_name=class_name,
                                       depth_unit=depth_unit, base=folder)
    if made:   # the table's mask column and the threshold give way to the masks asked for
        records = [replace(r, mask=None, mask_alpha=False, mask_method=made[0], mask_radius_m=made[1])
                   for r in records]
    masks = {"mask_method": mask, "mask_source": mask_source(mask, radius)} if made else {}
    summary = import_records(records, out_dir, source=source, prefix=prefix or source, threshold=threshold,
                             frames_per_shard=frames_per_shard, progress=progress, executor=executor,
                             attrs={"import": source, "poses": str(poses_csv), "unit": unit, "euler": euler, **masks})
    return summary, problems


def import_cvl(path, out_dir, *, unit="mm", euler="XYZ", fov=None, threshold=10, frames_per_shard=256,
               progress=None, executor=None):
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
                             frames_per_shard=frames_per_shard, progress=progress, executor=executor,
                             attrs={"import": "cvl", "unit": unit, "euler": euler})
    return summary, problems

"""Posed captures in the ``transforms.json`` layout (instant-ngp, nerfstudio; what COLMAP's
colmap2nerf, Polycam, Record3D and phone apps export) -> shards. docs/datasets.md, "transforms.json".

Read: ``PATH/transforms.json``, or where there is none ``transforms_train.json``,
``transforms_val.json`` and ``transforms_test.json`` in that order (the NeRF synthetic
layout), or the one JSON file PATH names. Per frame: ``file_path`` (relative to the JSON's
folder; a name without a suffix gets ``.png``), ``transform_matrix`` (4 x 4 camera-to-world,
OpenGL camera axes: x right, y up, looking down -z), optionally ``mask_path`` and
``depth_file_path``. Intrinsics: ``fl_x``, ``fl_y``, ``cx``, ``cy`` (pixel-corner origin, as
nerfstudio and COLMAP count), or ``camera_angle_x`` (and ``camera_angle_y``) with a centred
principal point; ``w``, ``h`` where given must match the image. Any of them, and the lens
(``camera_model`` and ``k1``, ``k2``, ``k3``, ``k4``, ``p1``, ``p2``), may be given once for all
frames or per frame. Lens distortion is removed with OpenCV as the frame is imported, so the
shard's images are those of the pinhole K.

The object frame is the capture's world frame moved to ``--center`` and scaled by ``--scale``
(metres per world unit): ``X_obj = scale * (X_world - center)``; conventions (OpenGL camera,
OpenCV camera, K's pixel origin) are converted by spm_data/core/poses.py. The mask of a frame is
its ``mask_path``, else a file of the same name in ``--mask-dir``, else its image's alpha channel
(a pixel at least half opaque is the object; an image opaque everywhere is skipped, listed); a
frame with none of them is refused. Depth images (uint16) are metric, one step being
``--depth-unit``. Frames are not taken as a walk of neighbouring views (``path_steps`` 0): SPM's
training rule uses each frame alone, as for views drawn at random.

Everything is checked before anything is written. A frame whose image (or mask_path, or depth
image) is missing or unreadable is skipped and listed with the others in the import's report;
``--strict`` refuses them instead, all in one error line (their count and the first three). A
frame without a matrix, a matrix that is not a rotation (core/poses.ROTATION_TOLERANCE), an
unknown camera model, a lens that would leave the masks empty, or no mask is one error line, for
the first such frame. Rotations are stored as the exact rotation nearest the file's.
"""

from __future__ import annotations

import json
import math
import warnings
from pathlib import Path

import numpy as np

from spm_data.core.poses import K_from_corner_origin, gl_camera_to_world_to_object
from spm_data.errors import SpmError, SpmWarning
from spm_data.formats.capture_images import lens_coverage, made_masks, mask_source
from spm_data.formats.importing import FrameRecord, import_records
from spm_data.io.images import IMAGE_SUFFIXES, ImageError, image_header

FILES = ("transforms.json",)
SPLIT_FILES = ("transforms_train.json", "transforms_val.json", "transforms_test.json")
# camera_model -> the distortion coefficients it reads, in OpenCV's order, and whether it is fisheye.
CAMERA_MODELS = {"OPENCV": (("k1", "k2", "p1", "p2", "k3"), False), "PINHOLE": ((), False),
                 "SIMPLE_PINHOLE": ((), False), "OPENCV_FISHEYE": (("k1", "k2", "k3", "k4"), True)}
CAMERA_KEYS = ("fl_x", "fl_y", "cx", "cy", "w", "h", "camera_angle_x", "camera_angle_y", "camera_model",
               "k1", "k2", "k3", "k4", "p1", "p2")
UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001}
MIN_LENS_COVERAGE = 0.5  # a lens that leaves less of the undistorted image inside the photo is refused
MAX_FILE_BYTES = 256 * 2**20  # a transforms.json larger than this is refused before it is read


def transforms_files(path) -> list[Path]:
    """The JSON files of a capture at ``path`` (a folder or one JSON file), in reading order."""
    path = Path(path)
    if path.is_file():
        if path.suffix.lower() != ".json":
            raise SpmError(f"{path}: not a transforms.json; give the capture's folder or its transforms.json")
        return [path]
    if not path.is_dir():
        raise SpmError(f"no capture at {path}: give a folder with transforms.json, or that file")
    found = [path / n for n in FILES if (path / n).is_file()] or [path / n for n in SPLIT_FILES
                                                                    if (path / n).is_file()]
    if not found:
        raise SpmError(f"{path}: no transforms.json (or transforms_train/_val/_test.json); export the capture "
                       "in the instant-ngp / nerfstudio layout")
    return found


def read_transforms(path: Path) -> dict:
    """One transforms JSON as a dict with a list of frames; SpmError naming the file otherwise."""
    try:
        if path.stat().st_size > MAX_FILE_BYTES:
            raise SpmError(f"{path}: {path.stat().st_size:,} bytes is over the limit of {MAX_FILE_BYTES:,}")
        data = json.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise SpmError(f"cannot read {path}: {exc.strerror or exc}") from None
    except RecursionError:
        raise SpmError(f"{path}: nested too deeply to be a transforms.json; give the capture's "
                       "transforms.json") from None
    except (UnicodeDecodeError, ValueError) as exc:
        raise SpmError(f"{path}: not a JSON file ({str(exc).splitlines()[0]}); give the capture's "
                       "transforms.json") from None
    if not isinstance(data, dict) or not isinstance(data.get("frames"), list):
        raise SpmError(f"{path}: no list of \"frames\"; expected instant-ngp's / nerfstudio's transforms.json")
    if not data["frames"]:
        raise SpmError(f"{path}: \"frames\" is empty; nothing to import")
    return data


def _number(camera: dict, key: str, where: str, positive: bool = False) -> float:
    value = camera[key]
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) \
            or (positive and value <= 0):
        want = "a finite number > 0" if positive else "a finite number"
        raise SpmError(f"{where}: {key} is {value!r}; expected {want}, fix the file")
    return float(value)


def frame_matrix(frame: dict, where: str) -> np.ndarray:
    """(4, 4) camera-to-world of a frame; SpmError naming the frame when it is missing or not a pose."""
    if "transform_matrix" not in frame:
        raise SpmError(f"{where}: no transform_matrix; every frame needs its 4x4 camera-to-world matrix")
    try:
        M = np.asarray(frame["transform_matrix"], dtype=np.float64)
    except (TypeError, ValueError):
        raise SpmError(f"{where}: transform_matrix is not a 4x4 list of numbers; fix the file") from None
    if M.shape == (3, 4):
        M = np.vstack([M, [0.0, 0.0, 0.0, 1.0]])
    if M.shape != (4, 4) or not np.isfinite(M).all():
        raise SpmError(f"{where}: transform_matrix has shape {M.shape} or a non-finite value; expected 4x4 finite "
                       "numbers, fix the file")
    return M


def intrinsics(camera: dict, width: int, height: int, where: str) -> np.ndarray:
    """K (3, 3), OpenCV pixel centres, of a frame's camera (its keys over the file's) for an image
    of ``width`` x ``height``: from fl_x, fl_y, cx, cy (pixel-corner origin) or camera_angle_x/_y."""
    for key, size in (("w", width), ("h", height)):
        if key in camera and _number(camera, key, where, positive=True) != size:
            raise SpmError(f"{where}: the image is {width}x{height}, the file says {key} = {camera[key]}; give the "
                           "images the capture's intrinsics were made for")
    if "fl_x" in camera:
        fx = _number(camera, "fl_x", where, positive=True)
        fy = _number(camera, "fl_y", where, positive=True) if "fl_y" in camera else fx
    elif "camera_angle_x" in camera:
        angle = _number(camera, "camera_angle_x", where, positive=True)
        if angle >= math.pi:
            raise SpmError(f"{where}: camera_angle_x is {angle}; expected radians in (0, pi), fix the file")
        fx = 0.5 * width / math.tan(0.5 * angle)
        fy = 0.5 * height / math.tan(0.5 * _number(camera, "camera_angle_y", where, positive=True)) \
            if "camera_angle_y" in camera else fx
    else:
        raise SpmError(f"{where}: no intrinsics; expected fl_x (and fl_y, cx, cy) or camera_angle_x")
    cx = _number(camera, "cx", where) if "cx" in camera else width / 2.0
    cy = _number(camera, "cy", where) if "cy" in camera else height / 2.0
    return K_from_corner_origin([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])


def lens(camera: dict, where: str) -> tuple[tuple, bool]:
    """(distortion coefficients in OpenCV's order, fisheye) of a frame's camera; () when none."""
    model = camera.get("camera_model", "OPENCV")
    if model not in CAMERA_MODELS:
        raise SpmError(f"{where}: camera_model {model!r} is not one this importer can undistort; expected one of "
                       f"{', '.join(CAMERA_MODELS)}")
    keys, fisheye = CAMERA_MODELS[model]
    unknown = [k for k in ("k1", "k2", "k3", "k4", "p1", "p2") if k not in keys and camera.get(k, 0) != 0]
    if unknown:
        raise SpmError(f"{where}: camera_model {model} has no {', '.join(unknown)}, yet the file gives them; fix "
                       "camera_model or the coefficients")
    coefficients = tuple(_number(camera, k, where) if k in camera else 0.0 for k in keys)
    # Zero coefficients are a pinhole in OpenCV's model, but an equidistant lens in its fisheye one.
    return (coefficients if any(coefficients) or fisheye else ()), fisheye


def _image_path(base: Path, name, where: str) -> Path:
    if not isinstance(name, str) or not name.strip():
        raise SpmError(f"{where}: no file_path; every frame names its image")
    path = base / name
    if not path.suffix and not _is_file(path):
        path = path.with_suffix(".png")  # the NeRF synthetic layout leaves the suffix out
    return path


def _is_file(path: Path) -> bool:
    """Whether ``path`` is a file; False for a name the system refuses (too long, a NUL byte)."""
    try:
        return path.is_file()
    except (OSError, ValueError):
        return False


def _header(path: Path, what: str) -> tuple[int, int, bool]:
    """(width, height, alpha) of a frame's image, mask or depth image; ImageError ("WHAT PATH is
    missing", "... not a readable image") when it cannot be read: the frame is skipped, listed."""
    shown = str(path) if len(str(path)) <= 200 else f"{str(path)[:100]}... ({len(str(path))} characters)"
    if not _is_file(path):
        raise ImageError(f"{what} {shown} is missing")
    try:
        return image_header(str(path))
    except ImageError as exc:
        raise ImageError(f"{what} {exc}") from None


def _mask_in(folder: Path | None, image: Path) -> Path | None:
    if folder is None:
        return None
    for candidate in [folder / image.name] + [folder / (image.stem + s) for s in IMAGE_SUFFIXES]:
        if _is_file(candidate):
            return candidate
    return None


def _center(center) -> np.ndarray:
    """``--center`` as given (text "x,y,z" or three numbers) -> (3,) float64."""
    return parse_center(center if isinstance(center, str) else ",".join(map(str, np.ravel(center))))


def parse_center(text) -> np.ndarray:
    """``--center`` "x,y,z" -> (3,) float64; SpmError for anything else."""
    try:
        center = np.array([float(v) for v in str(text).split(",")], dtype=np.float64)
    except ValueError:
        center = np.zeros(0)
    if center.shape != (3,) or not np.isfinite(center).all():
        raise SpmError(f"--center expects x,y,z (three finite numbers in the capture's world units), got {text!r}")
    return center


def nerf_records(path, *, class_name=None, scale=1.0, center=(0.0, 0.0, 0.0), mask_dir=None, depth_unit="mm",
                 strict=False, mask=None, radius=None):
    """(records, problems) of every frame of a capture, each checked (matrix, intrinsics, lens, mask):
    SpmError naming the file and frame for the first that cannot be imported. A frame whose image,
    mask or depth image is missing or unreadable is skipped, listed in problems; with ``strict``
    they are refused together, in one SpmError (their count and the first few). ``mask``: one of
    MASK_METHODS, the mask every frame is given instead of its files' (``radius``: the sphere's,
    world units around ``center``)."""
    if not (isinstance(scale, (int, float)) and 0 < scale < math.inf):
        raise SpmError(f"--scale {scale}: expected metres per world unit, a finite number > 0")
    if depth_unit not in UNITS:
        raise SpmError(f"--depth-unit takes one of {', '.join(UNITS)}, got {depth_unit!r}")
    center = _center(center)
    mask_dir = Path(mask_dir) if mask_dir else None
    if mask_dir is not None and not mask_dir.is_dir():
        raise SpmError(f"--mask-dir {mask_dir}: no such folder")
    made = _made_masks(mask, radius, scale, mask_dir)
    files = transforms_files(path)
    root = files[0].parent
    name = class_name or root.resolve().name or "capture"
    records, problems, listed = [], [], 0
    for file in files:
        data = read_transforms(file)
        shared = {k: data[k] for k in CAMERA_KEYS if k in data}
        for i, frame in enumerate(data["frames"]):
            listed += 1
            where = f"{file}: frame {i}"
            if not isinstance(frame, dict):
                raise SpmError(f"{where}: expected an object with file_path and transform_matrix")
            image = _image_path(file.parent, frame.get("file_path"), where)
            where = f"{file}: frame {i} ({_short(frame.get('file_path'))})"
            try:
                records.append(_record(frame, {**shared, **{k: frame[k] for k in CAMERA_KEYS if k in frame}},
                                       image, file.parent, where, name=name, scale=scale, center=center,
                                       mask_dir=mask_dir, depth_scale=UNITS[depth_unit], index=len(records),
                                       made=made))
            except ImageError as exc:
                problems.append((f"frame {i} ({_short(frame.get('file_path'))})", str(exc)))
    if strict and problems:
        first = "; ".join(f"{what}: {why}" for what, why in problems[:3]) + ("; ..." if len(problems) > 3 else "")
        raise SpmError(f"{len(problems)} of {listed} frames cannot be read ({first}); restore those files, or drop "
                       "--strict to skip them")
    return records, problems


def _short(text, limit: int = 200) -> str:
    """``text`` as given, or its start and its length when it is longer than ``limit``."""
    text = str(text)
    return text if len(text) <= limit else f"{text[:limit // 2]}... ({len(text)} characters)"


def _made_masks(method, radius, scale, mask_dir) -> tuple:
    """(method, sphere radius in metres) of ``--mask``/``--radius``; () without --mask."""
    if method is not None and mask_dir is not None:
        raise SpmError(f"--mask {method} makes every frame's mask; give it or --mask-dir, not both")
    return made_masks(method, radius, scale, "the capture's world units", "--center")


def _record(frame, camera, image, base, where, *, name, scale, center, mask_dir, depth_scale, index,
            made=()) -> FrameRecord:
    """One frame's record; ``base``: the folder its JSON is in (paths are relative to it). ImageError
    when its image, mask or depth image is missing or unreadable (the frame is skipped)."""
    R, t = gl_camera_to_world_to_object(frame_matrix(frame, where), scale, center, where)
    width, height, alpha = _header(image, "image")
    K = intrinsics(camera, width, height, where)
    distortion, fisheye = lens(camera, where)
    covered = lens_coverage(K, distortion, fisheye, width, height)
    if covered < MIN_LENS_COVERAGE:
        raise SpmError(f"{where}: the lens ({', '.join(f'{d:g}' for d in distortion)}) leaves {covered:.0%} of the "
                       "undistorted image inside the photo, so its masks would be empty; check the distortion "
                       "coefficients")
    # --mask makes every mask; else the masks a user names win over the alpha (apps write opaque RGBA PNGs too).
    if made:
        mask, alpha = None, False
    elif isinstance(frame.get("mask_path"), str):
        mask = _image_path(base, frame["mask_path"], where)
        _header(mask, "mask")
    else:
        mask = _mask_in(mask_dir, image) or (image if alpha else None)
        if mask is None:
            hint = f"no {image.name} (any image suffix) in --mask-dir {mask_dir}" if mask_dir else \
                "give --mask-dir DIR with a mask of the same name per image"
            raise SpmError(f"{where}: no mask: the image has no alpha channel and the frame no mask_path; {hint}, "
                           "or make masks with --mask none|sphere|grabcut (docs/datasets.md)")
        alpha = mask == image
    depth = None
    if isinstance(frame.get("depth_file_path"), str):
        depth = _image_path(base, frame["depth_file_path"], where)
        _header(depth, "depth image")
    return FrameRecord(image=str(image), class_name=name, instance_name=name, instance_id=0, R=tuple(R.ravel()),
                       t=tuple(t), K=tuple(K.ravel()), mask=None if mask is None else str(mask), mask_alpha=bool(alpha),
                       depth=None if depth is None else str(depth), depth_scale_m=depth_scale,
                       path_index=index, distance=float(np.linalg.norm(t)), distortion=distortion, fisheye=fisheye,
                       mask_method=made[0] if made else "", mask_radius_m=made[1] if made else 0.0)


def import_nerf(path, out_dir, *, class_name=None, scale=None, center="0,0,0", mask_dir=None, depth_unit="mm",
                strict=False, mask=None, radius=None, max_side=None, frames_per_shard=256, progress=None,
                executor=None):
    """Import a transforms.json capture into ``out_dir``; returns (RunSummary, problems). ``scale``
    None: the world unit is taken as a metre (attribute length_unit "capture unit", and a warning)."""
    records, problems = nerf_records(path, class_name=class_name, scale=1.0 if scale is None else scale,
                                     center=center, mask_dir=mask_dir, depth_unit=depth_unit, strict=strict,
                                     mask=mask, radius=radius)
    if problems and records:   # said now, in one line; the summary lists each at the end
        first = ", ".join(what for what, _ in problems[:3])
        warnings.warn(SpmWarning(f"skipping {len(problems)} of {len(problems) + len(records)} frames whose image, mask "
                                 f"or depth is missing or unreadable ({first}{', ...' if len(problems) > 3 else ''}); "
                                 "--strict refuses them"))
    attrs = {"import": "nerf", "transforms": json.dumps([str(f) for f in transforms_files(path)]),
             "scale": 1.0 if scale is None else float(scale), "length_unit": "m" if scale else "capture unit",
             "center": json.dumps(_center(center).tolist()), "mask_source": mask_source(mask, radius),
             "mask_method": mask or "file", "path_steps": 0}
    summary = import_records(records, out_dir, source="nerf", prefix="nerf", frames_per_shard=frames_per_shard,
                             attrs=attrs, progress=progress, executor=executor, problems=problems, max_side=max_side)
    if scale is None:
        warnings.warn(SpmWarning("no --scale: the capture's world unit is taken as 1 m, so the reports' mm are "
                                 "thousandths of that unit; give --scale (metres per unit) for true mm"))
    return summary, problems

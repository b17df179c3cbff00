"""The library calls behind ``spm train``, ``spm evaluate`` and ``spm predict``."""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path

import numpy as np

from spm_data.errors import SpmError, one_line
from spm_data.io.outputs import removing_created
from spm_data.io.images import ImageError, decode_bytes
from spm_model.dataset import FeatureTable, load_features
from spm_model.estimator import ModelError, SPMEstimator
from spm_model.model_files import load_model_file
from spm_model.evaluation import evaluate, frame_errors
from spm_model.features import FeatureConfig, FeatureError
from spm_model.frames import Frames
from spm_model.methods import MIN_TRAIN_FRAMES, load_estimator_class
from spm_model.metrics import summarise
from spm_model.report import check_report_folder, summary_text, write_error, write_report
from spm_model.surface_metrics import mesh_keys
from spm_model.template import TemplatePose

LABEL_NAMES = ("rx", "ry", "rz", "tx", "ty", "tz")


def check_classes(table: FeatureTable) -> dict:
    """Frames with training features per class; ModelError for a class with too few."""
    counts = {}
    usable = np.isfinite(table.train_vector).all(axis=1)
    for c in sorted(set(table.class_name.tolist())):
        counts[c] = int(usable[table.class_name == c].sum())
        if counts[c] < MIN_TRAIN_FRAMES:
            total = int((table.class_name == c).sum())
            raise ModelError(f"class {c!r} has {counts[c]} of {total} frames with features (need at least "
                             f"{MIN_TRAIN_FRAMES}); render more views or larger images, or leave its shards out")
    return counts


def load_estimators(specs) -> dict:
    """{name: class} of ``--estimator MODULE:CLASS`` values (name: CLASS, or MODULE:CLASS if two share it)."""
    classes = {spec: load_estimator_class(spec) for spec in dict.fromkeys(specs or ())}
    short = [spec.split(":")[1] for spec in classes]
    return {(spec.split(":")[1] if short.count(spec.split(":")[1]) == 1 else spec): cls
            for spec, cls in classes.items()}


def train(shards, report_dir=None, *, protocol: str = "loco", runs: int = 3,
          features: FeatureConfig = FeatureConfig(), model_params: dict | None = None, progress=None,
          log=lambda message: None, command: str = "spm train", executor=None, estimators=(),
          allow_partial: bool = False) -> dict:
    """Features of every shard under ``shards`` (cached), the evaluation protocol
    over ``runs`` seeds for every built-in method and each ``estimators`` entry
    ('MODULE:CLASS'), final models on every frame, and the report files.
    Returns {"report": folder, "model", "reference_model": paths, "summary", "evaluation", "text"}."""
    if runs < 1:
        raise ModelError(f"--runs must be at least 1, got {runs}")
    out = check_report_folder(report_dir if report_dir else Path(shards) / "report")  # before any work
    plugins = load_estimators(estimators)
    table = load_features(shards, features, progress=progress, executor=executor,
                          allow_partial=allow_partial)
    counts = check_classes(table)
    log(f"{len(table)} frames, {len(counts)} classes: " + ", ".join(f"{c} {n}" for c, n in counts.items())
        + " (frames with training features)")
    alone = int((table.train_neighbours == 0).sum())
    if alone:
        log(f"{alone} frames have no 5-degree path neighbour in their shard; their training features "
            "use every keypoint in the mask (docs/method.md)")
    model_params = dict(model_params or {}, features=features)
    evaluation = evaluate(table, protocol, runs, model_params, estimators=plugins, report=log)
    usable = np.isfinite(table.train_vector).all(axis=1)
    model = SPMEstimator(**model_params).fit(table.train_vector[usable], table.pose[usable])
    reference = TemplatePose().fit(Frames(table), table.pose)
    context = {"command": command, "shards": str(shards), "frames": len(table), "train_features": int(usable.sum()),
               "query_features": int(np.isfinite(table.query_vector).all(axis=1).sum()),
               "without_path_neighbour": int((table.train_neighbours == 0).sum()),
               "frames_per_class": {c: int((table.class_name == c).sum()) for c in counts},
               "model_params": {k: v for k, v in model_params.items() if k != "features"},
               "features": asdict(features), "estimators": {name: f"{cls.__module__}:{cls.__qualname__}"
                                                            for name, cls in plugins.items()}}
    try:
        with removing_created(out / "model.npz"):  # a report folder this run made goes again on failure
            out.mkdir(parents=True, exist_ok=True)
            model_path = model.save(out / "model.npz")
            reference_path = reference.save(out / "reference-model.npz")
            summary = write_report(evaluation, context, out)
    except OSError as exc:
        raise write_error(out, exc) from None
    return {"report": out, "model": model_path, "reference_model": reference_path, "summary": summary,
            "evaluation": evaluation, "text": summary_text(summary)}


def load_model(path):
    """A model file from ``spm train``: an SPMEstimator (model.npz) or a TemplatePose (reference-model.npz).
    ModelError naming the file for a missing, truncated, corrupt or foreign one."""
    header, arrays = load_model_file(path)  # read once
    kinds = {"spm": SPMEstimator, "template": TemplatePose}
    if header.get("kind") not in kinds:
        raise ModelError(f"{path}: not an spm model file (kind {header.get('kind')!r}, expected one of "
                         f"{sorted(kinds)}); give the model.npz or reference-model.npz that spm train wrote")
    try:
        model = kinds[header["kind"]].from_model_file(header, arrays)
        model.check_loaded()
    except (KeyError, TypeError, ValueError, IndexError, AttributeError, SpmError) as exc:
        problem = (f"no {exc.args[0]!r} in it" if isinstance(exc, KeyError) and exc.args else
                   f"{type(exc).__name__}: {exc}" if isinstance(exc, IndexError) else str(exc))
    else:
        return model
    raise ModelError(f"{path}: damaged spm model file ({one_line(problem)}); retrain it with spm train")


def evaluate_model(model_path, shards, *, progress=None, executor=None,
                   allow_partial: bool = False) -> dict:
    """Score a saved model (SPM or reference) on every frame under ``shards``:
    {"classes": {class: summary}, "all": summary} (summaries: spm_model/metrics.py)."""
    model = load_model(model_path)
    features = model.features if isinstance(model, SPMEstimator) else FeatureConfig()
    table = load_features(shards, features, progress=progress, executor=executor,
                          allow_partial=allow_partial)
    if isinstance(model, SPMEstimator):
        ok = np.isfinite(table.query_vector).all(axis=1)
        pred = np.full((len(table), 6), np.nan)
        if ok.any():
            pred[ok] = model.predict(table.query_vector[ok])
    else:
        pred = model.predict(Frames(table))
    index = np.arange(len(table))
    errors = frame_errors(table, index, pred, mesh_keys(table.shard, table.instance_id))
    per_class = {}
    for c in sorted(set(table.class_name.tolist())):
        sel = table.class_name == c
        per_class[c] = summarise({k: v[sel] for k, v in errors.items()})
    return {"classes": per_class, "all": summarise(errors)}


def roi_mask(roi, width: int, height: int) -> np.ndarray:
    """(height, width) uint8 mask of the region of interest ``(x, y, w, h)`` (pixels); ModelError
    unless the box lies inside the image and is not empty (never clipped or wrapped)."""
    x, y, w, h = (int(v) for v in roi)
    if x < 0 or y < 0:
        problem = "starts at a negative x or y"
    elif w < 1 or h < 1:
        problem = "is empty (width and height must be at least 1)"
    elif x >= width or y >= height:
        problem = "lies outside the image"
    elif x + w > width or y + h > height:
        problem = f"reaches outside the image (x + width = {x + w}, y + height = {y + h})"
    else:
        mask = np.zeros((height, width), np.uint8)
        mask[y: y + h, x: x + w] = 1
        return mask
    raise ModelError(f"--roi {x},{y},{w},{h} {problem}; the image is {width}x{height} pixels: give a box inside it "
                     f"(x, y >= 0, width, height >= 1, x + width <= {width}, y + height <= {height})")


def read_image(path) -> np.ndarray:
    """(H, W, 3) uint8 RGB of an image file for ``spm predict``; ImageError with the reason alone."""
    try:
        data = Path(path).read_bytes()
    except FileNotFoundError:
        raise ImageError("no such file") from None
    except IsADirectoryError:
        raise ImageError("is a folder, not an image file") from None
    except OSError as exc:
        raise ImageError(f"cannot read ({exc.strerror or exc})") from None
    return decode_bytes(data)


def read_mask(path) -> np.ndarray:
    """(H, W) bool object mask of ``--mask`` (non-zero = object); ModelError naming it."""
    try:
        with open(path, "rb") as fh:
            m = decode_bytes(fh.read(), mode="raw")
    except FileNotFoundError:
        raise ModelError(f"--mask {path}: no such file") from None
    except OSError as exc:
        raise ModelError(f"--mask {path}: cannot read ({exc.strerror or exc})") from None
    except ImageError as exc:
        raise ModelError(f"--mask {path}: {exc}") from None
    if m.ndim == 3:  # colour: any non-zero colour channel (alpha ignored)
        m = m[..., :3] if m.shape[2] >= 3 else m[..., :1]
        m = m.max(axis=2)
    mask = m > 0
    if not mask.any():
        raise ModelError(f"--mask {path}: no object pixel (every value is 0); give a mask with the object non-zero")
    return mask


def predict_images(model_path, images, *, roi=None, mask_path=None) -> list[dict]:
    """One result per image, in order: {"image", "pose": {rx..tz}[, "keypoints", "eccentricity"]},
    or {"image", "error": reason} when that image cannot be read (missing, not an image,
    truncated, over Pillow's decompression-bomb limit), the region of interest does not fit
    it, or the model finds no pose in it. The model and ``mask_path`` are read first: a
    problem with either raises ModelError (no image is read)."""
    model = load_model(model_path)
    mask = read_mask(mask_path) if mask_path is not None else None
    results = []
    for image in images:
        try:
            rgb = read_image(image)
            h, w = rgb.shape[:2]
            this_mask = roi_mask(roi, w, h) if roi is not None else mask
            if this_mask is not None and this_mask.shape != (h, w):
                raise ModelError(f"--mask {mask_path} is {this_mask.shape[1]}x{this_mask.shape[0]} pixels, the image "
                                 f"{w}x{h}; give a mask of the image's size")
            out = model.predict_image(rgb, this_mask)
            pose = np.asarray(out["pose"], dtype=np.float64)
            if pose.shape != (6,) or not np.isfinite(pose).all():
                raise ModelError("the model found no pose (no object in the mask or region of interest)")
            results.append({"image": str(image), "pose": dict(zip(LABEL_NAMES, map(float, pose))),
                            **({"keypoints": int(out["keypoints"]), "eccentricity": float(out["eccentricity"])}
                               if "keypoints" in out else {})})
        except (ImageError, FeatureError, ModelError) as exc:
            results.append({"image": str(image), "error": one_line(exc)})
    return results


def format_predictions(results: list[dict], as_json: bool) -> str:
    """What ``spm predict`` prints on stdout: JSON of every result (failed images as
    {"image", "error"}), or one text line per image that got a pose ("" if none did)."""
    if as_json:
        return json.dumps(results, indent=2)
    lines = []
    for r in results:
        if "error" not in r:
            p = r["pose"]
            extra = f"  [{r['keypoints']} keypoints]" if "keypoints" in r else ""
            lines.append(f"{r['image']}: rx {p['rx']:.1f} ry {p['ry']:.1f} rz {p['rz']:.1f} deg, "
                         f"t ({p['tx']:.3f}, {p['ty']:.3f}, {p['tz']:.3f}) m{extra}")
    return "\n".join(lines)


def prediction_errors(results: list[dict]) -> list[str]:
    """One line per failed image, in order, for stderr: "IMAGE: reason" (the CLI adds "error: ")."""
    return [f"{r['image']}: {r['error']}" for r in results if "error" in r]

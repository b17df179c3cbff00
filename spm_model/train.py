"""The library calls behind ``spm train``, ``spm evaluate`` and ``spm predict``."""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path

import numpy as np

from spm_data.importing import ImageError, decode_image, read_bytes
from spm_model.dataset import FeatureTable, load_features
from spm_model.estimator import ModelError, SPMEstimator, load_model_file
from spm_model.evaluation import evaluate, frame_errors
from spm_model.features import FeatureConfig, FeatureError
from spm_model.frames import Frames
from spm_model.methods import MIN_TRAIN_FRAMES, load_estimator_class
from spm_model.metrics import summarise
from spm_model.report import summary_text, write_report
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


def train(shards, report_dir=None, *, protocol: str = "loco", runs: int = 3, workers: int = 1,
          features: FeatureConfig = FeatureConfig(), model_params: dict | None = None, progress=None,
          log=lambda message: None, command: str = "spm train", executor=None, estimators=()) -> dict:
    """Features of every shard under ``shards`` (cached), the evaluation protocol
    over ``runs`` seeds for every built-in method and each ``estimators`` entry
    ('MODULE:CLASS'), final models on every frame, and the report files.
    Returns {"report": folder, "model", "reference_model": paths, "summary", "evaluation", "text"}."""
    if runs < 1:
        raise ModelError(f"--runs must be at least 1, got {runs}")
    plugins = load_estimators(estimators)
    table = load_features(shards, features, workers=workers, progress=progress, executor=executor)
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
    out = Path(report_dir) if report_dir else Path(shards) / "report"
    out.mkdir(parents=True, exist_ok=True)
    model_path = model.save(out / "model.npz")
    reference_path = reference.save(out / "reference-model.npz")
    context = {"command": command, "shards": str(shards), "frames": len(table), "train_features": int(usable.sum()),
               "query_features": int(np.isfinite(table.query_vector).all(axis=1).sum()),
               "without_path_neighbour": int((table.train_neighbours == 0).sum()),
               "frames_per_class": {c: int((table.class_name == c).sum()) for c in counts},
               "model_params": {k: v for k, v in model_params.items() if k != "features"},
               "features": asdict(features), "estimators": {name: f"{cls.__module__}:{cls.__qualname__}"
                                                            for name, cls in plugins.items()}}
    summary = write_report(evaluation, context, out)
    return {"report": out, "model": model_path, "reference_model": reference_path, "summary": summary,
            "evaluation": evaluation, "text": summary_text(summary)}


def load_model(path):
    """A model file from ``spm train``: an SPMEstimator (model.npz) or a TemplatePose (reference-model.npz)."""
    header, _ = load_model_file(path)
    kinds = {"spm": SPMEstimator, "template": TemplatePose}
    if header.get("kind") not in kinds:
        raise ModelError(f"{path}: unknown model kind {header.get('kind')!r}; expected one of {sorted(kinds)}")
    return kinds[header["kind"]].load(path)


def evaluate_model(model_path, shards, *, workers: int = 1, progress=None, executor=None) -> dict:
    """Score a saved model (SPM or reference) on every frame under ``shards``:
    {"classes": {class: summary}, "all": summary} (summaries: spm_model/metrics.py)."""
    model = load_model(model_path)
    features = model.features if isinstance(model, SPMEstimator) else FeatureConfig()
    table = load_features(shards, features, workers=workers, progress=progress, executor=executor)
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


def _roi_mask(shape, roi):
    x, y, w, h = roi
    mask = np.zeros(shape[:2], np.uint8)
    mask[max(0, y): y + h, max(0, x): x + w] = 1
    if not mask.any():
        raise ModelError(f"region of interest {roi} lies outside the {shape[1]}x{shape[0]} image")
    return mask


def predict_images(model_path, images, *, roi=None, mask_path=None) -> list[dict]:
    """One result per image: {"image", "pose": {rx..tz}, "keypoints", "eccentricity"}
    or {"image", "error"} when the image cannot be read or has too few keypoints."""
    model = load_model(model_path)
    mask = None
    if mask_path is not None:
        try:
            mask = decode_image(read_bytes(str(mask_path)), str(mask_path), mode="raw")
        except ImageError as exc:
            raise ModelError(str(exc)) from None
        mask = (mask.max(axis=2) if mask.ndim == 3 else mask) > 0
    results = []
    for image in images:
        try:
            rgb = decode_image(read_bytes(str(image)), str(image))
            this_mask = _roi_mask(rgb.shape, roi) if roi else mask
            if this_mask is not None and this_mask.shape != rgb.shape[:2]:
                raise ModelError(f"mask is {this_mask.shape[1]}x{this_mask.shape[0]}, image {rgb.shape[1]}x{rgb.shape[0]}")
            out = model.predict_image(rgb, this_mask)
            results.append({"image": str(image), "pose": dict(zip(LABEL_NAMES, map(float, out["pose"]))),
                            **({"keypoints": int(out["keypoints"]), "eccentricity": float(out["eccentricity"])}
                               if "keypoints" in out else {})})
        except (ImageError, FeatureError, ModelError) as exc:
            results.append({"image": str(image), "error": str(exc)})
    return results


def format_predictions(results: list[dict], as_json: bool) -> str:
    if as_json:
        return json.dumps(results, indent=2)
    lines = []
    for r in results:
        if "error" in r:
            lines.append(f"{r['image']}: error: {r['error']}")
        else:
            p = r["pose"]
            extra = f"  [{r['keypoints']} keypoints]" if "keypoints" in r else ""
            lines.append(f"{r['image']}: rx {p['rx']:.1f} ry {p['ry']:.1f} rz {p['rz']:.1f} deg, "
                         f"t ({p['tx']:.3f}, {p['ty']:.3f}, {p['tz']:.3f}) m{extra}")
    return "\n".join(lines)

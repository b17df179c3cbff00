"""The library call behind ``spm evaluate``: a saved model scored on a folder of shards."""

from __future__ import annotations

import numpy as np

from spm_data.errors import SpmError, one_line
from spm_model.errors import ModelError
from spm_model.base.frames import Frames
from spm_model.base.model_files import load_model_file
from spm_model.bench.feature_cache import load_features, progress_phase
from spm_model.bench.metrics import summarise
from spm_model.bench.scoring import frame_errors
from spm_model.bench.surface_metrics import mesh_keys
from spm_model.methods.registry import SAVED_MODELS
from spm_model.methods.cnn import CNNPose, check_device
from spm_model.spm.estimator import SPMEstimator
from spm_model.spm.features import FeatureConfig


def load_model(path, device: str | None = None):
    """A model file from ``spm train``: the reading class of the registry row whose method the file's
    header ``kind`` names (SAVED_MODELS: an SPMEstimator from model.npz, a TemplatePose from
    reference-model.npz, a CNNPose from cnn-model.npz), a CNNPose to run on ``device`` (None: "auto",
    whatever device it was trained on). ModelError naming the file for a missing, truncated, corrupt or foreign one, and
    for a ``device`` torch cannot use or given with a model that is not a cnn one."""
    header, arrays = load_model_file(path)  # read once
    kinds = {name: method.model_class() for name, method in SAVED_MODELS.items()}
    if header.get("kind") not in kinds:
        *others, last = (m.model_file for m in SAVED_MODELS.values())
        files = f"{', '.join(others)} or {last}"
        raise ModelError(f"{path}: not an spm model file (kind {header.get('kind')!r}, expected one of "
                         f"{sorted(kinds)}); give the {files} that spm train wrote")
    getattr(kinds[header["kind"]], "check_available", lambda: None)()   # cnn: torch, or one line naming the extra
    try:
        model = kinds[header["kind"]].from_model_file(header, arrays)
        model.check_loaded()
    except (KeyError, TypeError, ValueError, IndexError, AttributeError, SpmError) as exc:
        problem = (f"no {exc.args[0]!r} in it" if isinstance(exc, KeyError) and exc.args else
                   f"{type(exc).__name__}: {exc}" if isinstance(exc, IndexError) else str(exc))
    else:
        return _on_device(model, path, device)
    raise ModelError(f"{path}: damaged spm model file ({one_line(problem)}); retrain it with spm train")


def _on_device(model, path, device: str | None):
    """``model`` set to run on ``device`` (a cnn model; None: auto); ModelError for any other model given one."""
    if not isinstance(model, CNNPose):
        if device is not None:
            raise ModelError(f"--device {device}: only a cnn model runs on a device, {path} is a "
                             f"{_method(model)} model; leave --device out")
        return model
    check_device(device or "auto")
    model.device = device or "auto"
    return model


def evaluate_model(model_path, shards, *, progress=None, executor=None,
                   allow_partial: bool = False, bop=None, device: str | None = None) -> dict:
    """Score a saved model (SPM or reference) on every frame under ``shards``:
    {"classes": {class: summary}, "all": summary} (summaries: spm_model/bench/metrics.py).
    progress: a callable taking count deltas, told each step (feature_cache.progress_phase):
    the features (load_features), "predicting", "scoring". bop: a BopOutput (bop_output.py): also
    write the estimates as a BOP results file, method "spm", "template" or "cnn" (the result's ``bop_results``).
    device: where a cnn model runs (load_model)."""
    if bop is not None:
        bop.check(shards, allow_partial=allow_partial)
    model = load_model(model_path, device)
    features = model.features if isinstance(model, SPMEstimator) else FeatureConfig()
    table = load_features(shards, features, progress=progress, executor=executor,
                          allow_partial=allow_partial)
    progress_phase(progress, "predicting", None, None)
    if isinstance(model, SPMEstimator):
        ok = np.isfinite(table.query_vector).all(axis=1)
        pred = np.full((len(table), 6), np.nan)
        if ok.any():
            pred[ok] = model.predict(table.query_vector[ok])
    else:
        pred = model.predict(Frames(table))
    index = np.arange(len(table))
    progress_phase(progress, "scoring", None, None)
    errors = frame_errors(table, index, pred, mesh_keys(table.shard, table.instance_id))
    per_class = {}
    for c in sorted(set(table.class_name.tolist())):
        sel = table.class_name == c
        per_class[c] = summarise({k: v[sel] for k, v in errors.items()})
    written = [] if bop is None else bop.write(shards, table, {_method(model): (index, pred)}, allow_partial)
    written = [str(p) for p in written]
    return {"classes": per_class, "all": summarise(errors), **({"bop_results": written} if bop else {})}


def _method(model) -> str:
    """The method name of a results file: spm train's name of the method the model is of."""
    return next(name for name, method in SAVED_MODELS.items() if isinstance(model, method.model_class()))



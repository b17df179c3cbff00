"""Protocols and repeated runs: every method (spm_model/methods/registry.py, plus any
``--estimator``) on the same splits.

- ``loco`` (the paper's): for each class, train on the other classes, test on it.
- ``views``: new views of seen objects; a seeded 20% of the (instance, view)
  groups is held out per run. Occluded copies of a view share its group, so a
  view is never on both sides of a split.
- ``instances``: category-level pose; fold f tests the f-th instance of every
  class (in a seeded order per run) and trains on the others, so every frame
  is tested once per run and no instance is on both sides of a split.

Methods get frames (spm_model/base/frames.py) and the training poses, and return
(n, 6) labels; a NaN row is a frame without an estimate and counts as a
failure. Runs differ in their seed: the model's random choices, the views
split and the instances order (the features are extracted once, with a fixed
seed, and cached).
"""

from __future__ import annotations

import numpy as np

from spm_model.bench.feature_cache import FeatureTable
from spm_model.spm.estimator import ModelError
from spm_model.base.frames import Frames
from spm_model.methods.registry import builtin_methods, check_predictions
from spm_model.bench.metrics import SUM_THRESHOLDS, TOLERANCE_DEG, accuracy_curve, pose_errors, summarise, \
    success_rate, tolerance_rate
from spm_model.bench.surface_metrics import frame_surface_errors, mesh_keys

PROTOCOLS = ("loco", "views", "instances")
OCCLUSION_BINS = np.linspace(0.0, 1.0, 11)  # tenths of the object hidden; the last bin includes 1


def _instances_splits(table: FeatureTable, seed: int):
    rng = np.random.default_rng(seed)
    order = {}
    for c in sorted(set(table.class_name.tolist())):
        names = sorted(set(table.instance[table.class_name == c].tolist()))
        if len(names) < 2:
            raise ModelError(f"the instances protocol needs at least 2 instances of every class; {c!r} has "
                             f"{len(names)}; render more instances or use --protocol views")
        order[c] = [names[i] for i in rng.permutation(len(names))]
    out = []
    for fold in range(max(len(v) for v in order.values())):
        held = [names[fold] for names in order.values() if fold < len(names)]
        test = np.isin(table.instance, held)
        out.append((f"fold {fold + 1}", np.flatnonzero(~test), np.flatnonzero(test)))
    return out


def splits(table: FeatureTable, protocol: str, seed: int, held_out: float = 0.2):
    """[(what is tested, train index, test index)]: per class for loco, per fold
    for instances, one split for views."""
    classes = sorted(set(table.class_name.tolist()))
    if protocol == "loco":
        if len(classes) < 2:
            raise ModelError(f"leave-one-class-out needs at least 2 classes, found {classes}; "
                             "add shards of other classes or use --protocol views")
        return [(c, np.flatnonzero(table.class_name != c), np.flatnonzero(table.class_name == c)) for c in classes]
    if protocol == "views":
        groups = np.char.add(np.char.add(table.instance, "#"), table.path_index.astype(str))
        unique, inverse = np.unique(groups, return_inverse=True)
        test_groups = np.random.default_rng(seed).random(len(unique)) < held_out
        test = test_groups[inverse]
        return [("all", np.flatnonzero(~test), np.flatnonzero(test))]
    if protocol == "instances":
        return _instances_splits(table, seed)
    raise ModelError(f"protocol must be one of {PROTOCOLS}, got {protocol!r}")


def fit_predict(methods: dict, table: FeatureTable, train: np.ndarray, test: np.ndarray) -> dict:
    """{name: (len(test), 6) predictions} of every method fitted on ``train``."""
    out = {}
    for name, method in methods.items():
        fitted = method.fit(Frames(table, train), table.pose[train].copy())
        if fitted is None:
            raise ModelError(f"estimator {name}: fit(frames, poses) must return self, got None")
        out[name] = check_predictions(name, fitted.predict(Frames(table, test)), len(test))
    return out


def frame_errors(table: FeatureTable, index: np.ndarray, pred: np.ndarray, keys: list) -> dict:
    """Per-frame pose errors (spm_model/bench/metrics.py) and surface errors
    (spm_model/bench/surface_metrics.py) of predictions for the frames ``index``."""
    errors = pose_errors(pred, table.pose[index], table.label_measured[index])
    errors.update(frame_surface_errors(pred, table.pose[index], table.K[index], table.width[index],
                                       [keys[i] for i in index]))
    return errors


def _select(errors: dict, sel) -> dict:
    return {k: v[sel] for k, v in errors.items()}


def _occlusion_curve(table, index, errors):
    occ = table.occlusion_fraction[index]
    curve = {}
    for m, e in errors.items():
        rows = []
        for lo, hi in zip(OCCLUSION_BINS[:-1], OCCLUSION_BINS[1:]):
            sel = (occ >= lo) & ((occ < hi) | (hi == 1.0)) & ~np.isnan(e["rotation_max"])
            rows.append({"low": float(lo), "high": float(hi), "frames": int(sel.sum()),
                         "success_tol5": tolerance_rate(e["rotation_max"][sel], TOLERANCE_DEG),
                         **{f"success_sum{th:g}": success_rate(e["rotation_sum"][sel], th) for th in SUM_THRESHOLDS}})
        curve[m] = rows
    return curve


def _run(table, protocol, run, make_methods, keys, report):
    index_parts, prediction_parts = [], []
    for tested, train, test in splits(table, protocol, seed=run):
        if len(train) == 0:
            raise ModelError(f"{protocol} protocol, run {run + 1}: nothing left to train on when testing {tested}")
        if len(test) == 0:
            continue
        report(f"run {run + 1}: {protocol} test {tested} ({len(train)} train / {len(test)} test frames)")
        index_parts.append(test)
        prediction_parts.append(fit_predict(make_methods(run), table, train, test))
    if not index_parts:
        raise ModelError(f"{protocol} protocol, run {run + 1}: no frame was held out for testing "
                         f"({len(table)} frames); add views or instances, or use another protocol")
    index = np.concatenate(index_parts)
    names = list(prediction_parts[0])
    # Each method's per-frame errors once; the tables, curves and bins slice them.
    errors = {m: frame_errors(table, index, np.concatenate([p[m] for p in prediction_parts]), keys) for m in names}
    classes = sorted(set(table.class_name.tolist()))
    per_class = {}
    for c in classes:
        sel = table.class_name[index] == c
        if sel.any():
            per_class[c] = {m: summarise(_select(e, sel)) for m, e in errors.items()}
    curves = {m: accuracy_curve(e["geodesic"], int(e["rotation_measured"].sum())).tolist()
              if e["rotation_measured"].any() else None for m, e in errors.items()}
    return {"seed": run, "classes": per_class, "overall": {m: summarise(e) for m, e in errors.items()},
            "occlusion": _occlusion_curve(table, index, errors), "accuracy_curve": curves}


def evaluate(table: FeatureTable, protocol: str = "loco", runs: int = 3, model_params: dict | None = None,
             estimators: dict | None = None, report=lambda message: None, builtins=None) -> dict:
    """Every run x split for the built-in methods (``builtins``: their names, default
    all) and ``estimators`` ({name: class}, instantiated fresh per split): per-class
    and overall summaries per method, the geodesic accuracy curve and the occlusion
    bins. Returns {"protocol", "runs": [...], "eccentricity", "classes", "methods"}."""
    params = dict(model_params or {})
    features = params.pop("features")

    def make_methods(seed):
        methods = {k: v for k, v in builtin_methods(seed, features, params).items()
                   if builtins is None or k in builtins}
        methods.update({name: cls() for name, cls in (estimators or {}).items()})
        return methods

    keys = mesh_keys(table.shard, table.instance_id)
    results = [_run(table, protocol, run, make_methods, keys, report) for run in range(runs)]
    classes = sorted(set(table.class_name.tolist()))
    eccentricity = {}
    for c in classes:
        e = table.query_eccentricity[(table.class_name == c)]
        e = e[np.isfinite(e)]
        eccentricity[c] = {"mean": float(e.mean()) if len(e) else None, "std": float(e.std()) if len(e) else None,
                           "frames": int(len(e))}
    return {"protocol": protocol, "runs": results, "eccentricity": eccentricity, "classes": classes,
            "methods": list(results[0]["overall"])}

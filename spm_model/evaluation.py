"""Protocols and repeated runs: SPM and every baseline on the same splits.

- ``loco`` (the paper's): for each class, train on the other classes, test on it.
- ``views``: new views of seen objects; a seeded 20% of the (instance, view)
  groups is held out per run. Occluded copies of a view share its group, so a
  view is never on both sides of a split.

Training uses the frames' ``train`` features (path-neighbour keypoint rule),
testing their ``query`` features (a single image: keypoints in the mask). A
test frame without a query feature counts as a failure for SPM and KNN; the raw
image baselines (PCA, LS) estimate every frame. Runs differ in their seed: the
model's projection subset, noise copies and Nystrom centres, and the views split
(the features are extracted once, with a fixed seed, and cached).
"""

from __future__ import annotations

import numpy as np

from spm_model.baselines import KNNPose, LSPose, PCAPose
from spm_model.dataset import FeatureTable
from spm_model.estimator import ModelError, SPMEstimator
from spm_model.metrics import THRESHOLDS, pose_errors, success_rate, summarise

METHODS = ("spm", "knn1", "knn3", "pca", "ls")
PROTOCOLS = ("loco", "views")
MIN_TRAIN_FRAMES = 10
OCCLUSION_BINS = np.linspace(0.0, 1.0, 11)  # tenths of the object hidden; the last bin includes 1


def splits(table: FeatureTable, protocol: str, seed: int, held_out: float = 0.2):
    """[(class tested, train index, test index)]: per class for loco; one split for views."""
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
    raise ModelError(f"protocol must be one of {PROTOCOLS}, got {protocol!r}")


def fit_predict(table: FeatureTable, train: np.ndarray, test: np.ndarray, seed: int, model_params: dict) -> dict:
    """Predictions (len(test), 6) of every method, NaN where a method has no estimate."""
    ok_train = train[np.isfinite(table.train_vector[train]).all(axis=1)]
    if len(ok_train) < MIN_TRAIN_FRAMES:
        raise ModelError(f"only {len(ok_train)} training frames have features (need {MIN_TRAIN_FRAMES}); "
                         "render more views or larger images")
    ok_test = np.isfinite(table.query_vector[test]).all(axis=1)
    spm = SPMEstimator(**model_params, seed=seed).fit(table.train_vector[ok_train], table.pose[ok_train])
    out = {m: np.full((len(test), 6), np.nan) for m in METHODS}
    if ok_test.any():
        query = table.query_vector[test[ok_test]]
        out["spm"][ok_test] = spm.predict(query)
        train_z, query_z = spm.transform(table.train_vector[ok_train]), spm.transform(query)
        for k in (1, 3):
            out[f"knn{k}"][ok_test] = KNNPose(k=k).fit(train_z, table.pose[ok_train]).predict(query_z)
    raw_train, raw_test = table.raw[train], table.raw[test]
    out["pca"] = PCAPose().fit(raw_train, table.pose[train]).predict(raw_test)
    out["ls"] = LSPose().fit(raw_train, table.pose[train]).predict(raw_test)
    return out


def _select(errors: dict, sel) -> dict:
    return {k: v[sel] for k, v in errors.items()}


def _per_class(table, index, errors, classes):
    """{class: {method: summary}} from each method's per-frame errors over ``index``."""
    result = {}
    for c in classes:
        sel = table.class_name[index] == c
        if sel.any():
            result[c] = {m: summarise(_select(e, sel)) for m, e in errors.items()}
    return result


def _occlusion_curve(table, index, errors):
    occ = table.occlusion_fraction[index]
    curve = {}
    for m, e in errors.items():
        rot = e["rotation_sum"]
        rows = []
        for lo, hi in zip(OCCLUSION_BINS[:-1], OCCLUSION_BINS[1:]):
            sel = (occ >= lo) & ((occ < hi) | (hi == 1.0)) & ~np.isnan(rot)
            rows.append({"low": float(lo), "high": float(hi), "frames": int(sel.sum()),
                         **{f"success_{th:g}": success_rate(rot[sel], th) for th in THRESHOLDS}})
        curve[m] = rows
    return curve


def evaluate(table: FeatureTable, protocol: str = "loco", runs: int = 3, model_params: dict | None = None,
             report=lambda message: None) -> dict:
    """Every run x split: per-class summaries per method, and the occlusion curve
    (all test frames of a run pooled). Returns {"runs": [...]}."""
    model_params = dict(model_params or {})
    classes = sorted(set(table.class_name.tolist()))
    results = []
    for run in range(runs):
        index_parts, prediction_parts = [], []
        for tested, train, test in splits(table, protocol, seed=run):
            report(f"run {run + 1}/{runs}: {protocol} test {tested} ({len(train)} train / {len(test)} test frames)")
            if len(test) == 0:
                continue
            index_parts.append(test)
            prediction_parts.append(fit_predict(table, train, test, seed=run, model_params=model_params))
        index = np.concatenate(index_parts)
        # Each method's per-frame errors once; the tables and the curve slice them.
        errors = {m: pose_errors(np.concatenate([p[m] for p in prediction_parts]), table.pose[index],
                                 table.label_measured[index]) for m in METHODS}
        results.append({"seed": run, "classes": _per_class(table, index, errors, classes),
                        "overall": {m: summarise(e) for m, e in errors.items()},
                        "occlusion": _occlusion_curve(table, index, errors)})
    eccentricity = {}
    for c in classes:
        e = table.query_eccentricity[(table.class_name == c)]
        e = e[np.isfinite(e)]
        eccentricity[c] = {"mean": float(e.mean()) if len(e) else None, "std": float(e.std()) if len(e) else None,
                           "frames": int(len(e))}
    return {"protocol": protocol, "runs": results, "eccentricity": eccentricity, "classes": classes}

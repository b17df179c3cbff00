"""Protocols and repeated runs: every method (spm_model/methods/registry.py, plus any
``--estimator``) on the same splits.

- ``loco`` (the paper's): for each class, train on the other classes, test on it.
- ``views``: new views of seen objects; a seeded 20% of the (instance, view)
  groups is held out per run. Occluded copies of a view share its group, so a
  view is never on both sides of a split.
- ``instances``: category-level pose; fold f tests the f-th instance of every
  class (in a seeded order per run) and trains on the others, so every frame
  is tested once per run and no instance is on both sides of a split.
- ``offgrid`` (the paper's Fig. 5 as it ran it): train on every frame of one
  folder (a camera grid), test on every frame of another (views at random
  poses, occluded by rectangles or 3-D distractors); test frames whose
  instance is in the training folder are "seen", the others "unseen".

Methods get training frames (spm_model/base/frames.py) with their poses, then
test frames that hold only what a camera sees (image, visible mask, K), in a
seeded random order, and return (n, 6) labels; a NaN row is a frame without an
estimate and counts as a failure. ``train_occluded`` (the paper's Appendix,
training with noise): whether frames with occlusion train too; by default they
do under loco, views and instances (as before) and do not under offgrid.
Runs differ in their seed: the model's random choices, the views split, the
instances order and the test order (the features are extracted once, with a
fixed seed, and cached).
"""

from __future__ import annotations

import numpy as np

from spm_data.errors import ModelError
from spm_model.base.frames import Frames, camera_chunks, read_camera_frames
from spm_model.bench.feature_cache import FeatureTable
from spm_model.bench.metrics import SUM_THRESHOLDS, TOLERANCE_DEG, accuracy_curve, pose_errors, summarise, \
    success_rate, tolerance_rate
from spm_model.bench.surface_metrics import frame_surface_errors, mesh_keys
from spm_model.bench.symmetry_errors import instance_symmetries, symmetric_errors
from spm_model.methods.registry import builtin_methods, check_predictions

PROTOCOLS = ("loco", "views", "instances", "offgrid")
OCCLUSION_BINS = np.linspace(0.0, 1.0, 11)  # tenths of the object hidden; the last bin includes 1
OCCLUDERS = ("none", "rectangles", "distractors")


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
    for instances, one split for views and offgrid (offgrid: the table's ``test`` column)."""
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
    if protocol == "offgrid":
        if "test" not in table.arrays:
            raise ModelError("the offgrid protocol needs a test folder: give --test FOLDER (views rendered at "
                             "random poses, occluded; see README, Fig. 5)")
        return [("test folder", np.flatnonzero(~table.test), np.flatnonzero(table.test))]
    raise ModelError(f"protocol must be one of {PROTOCOLS}, got {protocol!r}")


def training_rows(table: FeatureTable, train: np.ndarray, train_occluded: bool) -> np.ndarray:
    """``train`` without its occluded frames unless ``train_occluded``."""
    return train if train_occluded else train[table.occlusion_fraction[train] <= 0]


def fit_predict(methods: dict, table: FeatureTable, train: np.ndarray, test: np.ndarray, seed: int = 0) -> dict:
    """{name: (len(test), 6) predictions, in ``test``'s order} of every method fitted on
    ``train``. Methods see the test frames as a camera gives them (CameraFrames), in a
    random order seeded by ``seed``, a bounded chunk of images at a time."""
    fitted = {}
    for name, method in methods.items():
        fitted[name] = method.fit(Frames(table, train), table.pose[train].copy())
        if fitted[name] is None:
            raise ModelError(f"estimator {name}: fit(frames, poses) must return self, got None")
    order = np.random.default_rng(seed).permutation(len(test))
    parts = {name: [] for name in methods}
    for chunk in camera_chunks(table, test[order]):
        frames = read_camera_frames(table, chunk)
        for name, model in fitted.items():
            parts[name].append(check_predictions(name, model.predict(frames), len(chunk)))
    out = {}
    for name, chunks in parts.items():
        pred = np.full((len(test), 6), np.nan)
        pred[order] = np.concatenate(chunks) if chunks else np.zeros((0, 6))
        out[name] = pred
    return out


def frame_errors(table: FeatureTable, index: np.ndarray, pred: np.ndarray, keys: list,
                 symmetries: list | None = None) -> dict:
    """Per-frame pose errors (spm_model/bench/metrics.py), surface errors
    (spm_model/bench/surface_metrics.py) and errors up to the declared symmetries
    (spm_model/bench/symmetry_errors.py) of predictions for the frames ``index``."""
    errors = pose_errors(pred, table.pose[index], table.label_measured[index])
    errors.update(frame_surface_errors(pred, table.pose[index], table.K[index], table.width[index],
                                       [keys[i] for i in index]))
    symmetries = instance_symmetries(keys) if symmetries is None else symmetries
    errors.update(symmetric_errors(pred, table.pose[index], [symmetries[i] for i in index]))
    return errors


def _select(errors: dict, sel) -> dict:
    return {k: v[sel] for k, v in errors.items()}


def occlusion_rows(occ: np.ndarray, errors: dict) -> list:
    """Per tenth of occlusion: frames, the paper's criteria (sum < 5°, sum < 3°, ±5°) and
    the geodesic median, over the frames of that bin (the last bin includes 1)."""
    rows = []
    for lo, hi in zip(OCCLUSION_BINS[:-1], OCCLUSION_BINS[1:]):
        sel = (occ >= lo) & ((occ < hi) | (hi == 1.0)) & ~np.isnan(errors["rotation_max"])
        geo, t = errors["geodesic"][sel], errors["translation"][sel]
        geo, t = geo[np.isfinite(geo)], t[np.isfinite(t)]
        rows.append({"low": float(lo), "high": float(hi), "frames": int(sel.sum()),
                     "success_tol5": tolerance_rate(errors["rotation_max"][sel], TOLERANCE_DEG),
                     **{f"success_sum{th:g}": success_rate(errors["rotation_sum"][sel], th) for th in SUM_THRESHOLDS},
                     "geodesic_median_deg": float(np.median(geo)) if len(geo) else None,
                     "translation_median_mm": 1000.0 * float(np.median(t)) if len(t) else None})
    return rows


def _occlusion_curves(table, index, errors) -> dict:
    """{group: {occluder: {method: rows}}}: every frame under "all"/"all"; by seen/unseen
    instance (offgrid) and by occluder kind where the test frames have them."""
    occ = table.occlusion_fraction[index]
    groups = {"all": np.ones(len(index), bool)}
    if "seen" in table.arrays:
        groups.update({"seen": table.seen[index], "unseen": ~table.seen[index]})
    occluder = table.arrays.get("occluder")
    out = {}
    for g, gsel in groups.items():
        if not gsel.any():
            continue
        kinds = {"all": gsel}
        if occluder is not None:
            for kind in OCCLUDERS[1:]:
                ksel = gsel & ((occluder[index] == kind) | (occluder[index] == "none"))
                if (occluder[index][gsel] == kind).any():
                    kinds[kind] = ksel  # this occluder's curve, starting from the unoccluded frames
        out[g] = {k: {m: occlusion_rows(occ[sel], _select(e, sel)) for m, e in errors.items()}
                  for k, sel in kinds.items()}
    return out


def _run(table, protocol, run, make_methods, keys, symmetries, report, train_occluded):
    index_parts, prediction_parts = [], []
    for tested, train, test in splits(table, protocol, seed=run):
        train = training_rows(table, train, train_occluded)
        if len(train) == 0:
            raise ModelError(f"{protocol} protocol, run {run + 1}: nothing left to train on when testing {tested}")
        if len(test) == 0:
            continue
        report(f"run {run + 1}: {protocol} test {tested} ({len(train)} train / {len(test)} test frames)")
        index_parts.append(test)
        prediction_parts.append(fit_predict(make_methods(run), table, train, test, seed=run))
    if not index_parts:
        raise ModelError(f"{protocol} protocol, run {run + 1}: no frame was held out for testing "
                         f"({len(table)} frames); add views or instances, or use another protocol")
    index = np.concatenate(index_parts)
    names = list(prediction_parts[0])
    # Each method's per-frame errors once; the tables, curves and bins slice them.
    errors = {m: frame_errors(table, index, np.concatenate([p[m] for p in prediction_parts]), keys, symmetries)
              for m in names}
    per_class = {}
    for c in sorted(set(table.class_name.tolist())):
        sel = table.class_name[index] == c
        if sel.any():
            per_class[c] = {m: summarise(_select(e, sel)) for m, e in errors.items()}
    curves = {m: accuracy_curve(e["geodesic"], int(e["rotation_measured"].sum())).tolist()
              if e["rotation_measured"].any() else None for m, e in errors.items()}
    curves_by = _occlusion_curves(table, index, errors)
    out = {"seed": run, "classes": per_class, "overall": {m: summarise(e) for m, e in errors.items()},
           "occlusion": curves_by["all"]["all"], "accuracy_curve": curves}
    if protocol == "offgrid":
        out["fig5"] = curves_by
        out["instances"] = {g: {m: summarise(_select(e, table.seen[index] == (g == "seen")))
                                for m, e in errors.items()}
                            for g in ("seen", "unseen") if (table.seen[index] == (g == "seen")).any()}
    return out


def evaluate(table: FeatureTable, protocol: str = "loco", runs: int = 3, model_params: dict | None = None,
             estimators: dict | None = None, report=lambda message: None, builtins=None,
             train_occluded: bool | None = None) -> dict:
    """Every run x split for the built-in methods (``builtins``: their names, default
    all) and ``estimators`` ({name: class}, instantiated fresh per split): per-class
    and overall summaries per method, the geodesic accuracy curve and the occlusion
    bins (offgrid: also per seen/unseen instance and occluder, "fig5").
    train_occluded: None for the protocol's default (module docstring).
    Returns {"protocol", "runs": [...], "eccentricity", "classes", "methods", "train_occluded"}."""
    if protocol not in PROTOCOLS:
        raise ModelError(f"protocol must be one of {PROTOCOLS}, got {protocol!r}")
    train_occluded = (protocol != "offgrid") if train_occluded is None else bool(train_occluded)
    params = dict(model_params or {})
    features = params.pop("features")

    def make_methods(seed):
        methods = {k: v for k, v in builtin_methods(seed, features, params).items()
                   if builtins is None or k in builtins}
        methods.update({name: cls() for name, cls in (estimators or {}).items()})
        return methods

    keys = mesh_keys(table.shard, table.instance_id)
    symmetries = instance_symmetries(keys)
    results = [_run(table, protocol, run, make_methods, keys, symmetries, report, train_occluded)
               for run in range(runs)]
    classes = sorted(set(table.class_name.tolist()))
    eccentricity = {}
    for c in classes:
        e = table.query_eccentricity[(table.class_name == c)]
        e = e[np.isfinite(e)]
        eccentricity[c] = {"mean": float(e.mean()) if len(e) else None, "std": float(e.std()) if len(e) else None,
                           "frames": int(len(e))}
    return {"protocol": protocol, "runs": results, "eccentricity": eccentricity, "classes": classes,
            "methods": list(results[0]["overall"]), "train_occluded": train_occluded}

"""Scoring a run: per-frame errors of every method's predictions (pose, surface, up to
symmetry), summaries per class and overall, accuracy curves, and success against
occlusion in tenths (the paper's Fig. 5), per seen/unseen instance and occluder."""

from __future__ import annotations

import numpy as np

from spm_model.bench.metrics import SUM_THRESHOLDS, TOLERANCE_DEG, accuracy_curve, intervals, pose_errors, \
    summarise, success_rate, tolerance_rate
from spm_model.bench.surface_metrics import frame_surface_errors
from spm_model.bench.symmetry_errors import instance_symmetries, symmetric_errors

OCCLUSION_BINS = np.linspace(0.0, 1.0, 11)  # tenths of the object hidden; the last bin includes 1
OCCLUDERS = ("none", "rectangles", "distractors")


def frame_errors(table, index: np.ndarray, pred: np.ndarray, keys: list,
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
    """Per tenth of occlusion: frames, of those the frames with an estimate, the paper's criteria
    (sum < 5°, sum < 3°, ±5°) with their 95% Wilson intervals (``ci95``) and the geodesic
    median, over the frames of that bin (the last bin includes 1)."""
    rows = []
    for lo, hi in zip(OCCLUSION_BINS[:-1], OCCLUSION_BINS[1:]):
        sel = (occ >= lo) & ((occ < hi) | (hi == 1.0)) & ~np.isnan(errors["rotation_max"])
        geo, t = errors["geodesic"][sel], errors["translation"][sel]
        geo, t = geo[np.isfinite(geo)], t[np.isfinite(t)]
        row = {"low": float(lo), "high": float(hi), "frames": int(sel.sum()),
               "estimated": int(np.isfinite(errors["rotation_max"][sel]).sum()),
               "success_tol5": tolerance_rate(errors["rotation_max"][sel], TOLERANCE_DEG),
               **{f"success_sum{th:g}": success_rate(errors["rotation_sum"][sel], th) for th in SUM_THRESHOLDS},
               "geodesic_median_deg": float(np.median(geo)) if len(geo) else None,
               "translation_median_mm": 1000.0 * float(np.median(t)) if len(t) else None}
        rows.append({**row, "ci95": intervals(row, dict.fromkeys(("success_tol5", "success_sum5", "success_sum3"),
                                                                  row["frames"]))})
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


def run_summary(table, protocol: str, run: int, parts: list) -> dict:
    """One run's results from its splits' outputs [(tested, training frames, test index,
    {method: per-frame errors (frame_errors)}, {"declined": {method: why}, "featured":
    {method: count or None}})]: per-class and overall summaries, accuracy curves, occlusion
    bins; with offgrid, the Fig. 5 curves and the seen/unseen summaries; ``splits`` (what each
    split tested), ``declined`` ({method: {split: why}}) and each overall entry's ``featured``
    (test frames the method found its features on, None where it does not say)."""
    index = np.concatenate([p[2] for p in parts])
    names = list(parts[0][3])
    # Each method's per-frame errors, scored per split (every error is a frame's own); the
    # tables, curves and bins slice them.
    errors = {m: {k: np.concatenate([p[3][m][k] for p in parts]) for k in parts[0][3][m]} for m in names}
    per_class = {}
    for c in sorted(set(table.class_name.tolist())):
        sel = table.class_name[index] == c
        if sel.any():
            per_class[c] = {m: summarise(_select(e, sel)) for m, e in errors.items()}
    curves = {m: accuracy_curve(e["geodesic"], int(e["rotation_measured"].sum())).tolist()
              if e["rotation_measured"].any() else None for m, e in errors.items()}
    curves_by = _occlusion_curves(table, index, errors)
    overall = {m: {**summarise(e), "featured": _featured(parts, m)} for m, e in errors.items()}
    declined = {m: {p[0]: p[4]["declined"][m] for p in parts if m in p[4]["declined"]} for m in names}
    out = {"seed": run, "splits": [p[0] for p in parts], "declined": {m: d for m, d in declined.items() if d},
           "classes": per_class, "overall": overall, "occlusion": curves_by["all"]["all"], "accuracy_curve": curves}
    if protocol == "offgrid":
        out["fig5"] = curves_by
        out["instances"] = {g: {m: summarise(_select(e, table.seen[index] == (g == "seen")))
                                for m, e in errors.items()}
                            for g in ("seen", "unseen") if (table.seen[index] == (g == "seen")).any()}
    return out




def _featured(parts: list, method: str) -> int | None:
    """Test frames of every split that ``method`` found its features on (0 where it declined);
    None when it does not say in a split it ran in."""
    counts = [p[4]["featured"].get(method) if method not in p[4]["declined"] else 0 for p in parts]
    return None if any(c is None for c in counts) else int(sum(counts))


def eccentricity(table) -> dict:
    """SPM's query ellipses per class: {class: {"mean", "std", "frames"}}."""
    out = {}
    for c in sorted(set(table.class_name.tolist())):
        e = table.query_eccentricity[(table.class_name == c)]
        e = e[np.isfinite(e)]
        out[c] = {"mean": float(e.mean()) if len(e) else None, "std": float(e.std()) if len(e) else None,
                  "frames": int(len(e))}
    return out

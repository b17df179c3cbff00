"""Pose errors and the paper's success criterion (§3.2, after Hinterstoisser et al. 2007).

A pose estimate is a success when the sum of the absolute rotation-angle errors
(rx, ry, rz, each wrapped to (-180, 180]) is below 5 degrees (3 in the second
column). Only label components a dataset measured count (``label_measured``):
COIL-100, for instance, measures one angle, so its success uses that angle, its
geodesic error is undefined (NaN) and so is its translation error.
"""

from __future__ import annotations

import numpy as np

from spm_data.poses import label_to_pose, wrap_degrees

THRESHOLDS = (5.0, 3.0)
# "Below" means below by more than this: on a 5-degree view grid a neighbour's
# error is 5 degrees up to float noise, which must not decide success.
TOLERANCE = 1e-6


def pose_errors(pred: np.ndarray, true: np.ndarray, measured: np.ndarray | None = None) -> dict:
    """pred, true (n, 6) labels (degrees, metres); measured (n, 6) bool or None (all).

    Returns (n,) arrays: ``rotation_sum`` (degrees, summed over the measured
    angles; NaN when no angle is measured; inf when pred is NaN, i.e. no
    estimate), ``geodesic`` (degrees, the angle of R_pred^T R_true; NaN unless
    all three angles are measured and estimated), ``translation`` (metres,
    ||t_pred - t_true||; NaN unless all of t is measured and estimated)."""
    pred = np.asarray(pred, dtype=np.float64).reshape(-1, 6)
    true = np.asarray(true, dtype=np.float64).reshape(-1, 6)
    measured = np.ones(true.shape, bool) if measured is None else np.asarray(measured, bool).reshape(-1, 6)
    angle = np.abs(wrap_degrees(pred[:, :3] - true[:, :3]))
    has_angle = measured[:, :3].any(axis=1)
    rotation_sum = np.where(measured[:, :3], angle, 0.0).sum(axis=1)
    rotation_sum[~np.isfinite(rotation_sum)] = np.inf  # no estimate: a failure, never a success
    rotation_sum[~has_angle] = np.nan
    geodesic = np.full(len(pred), np.nan)
    full = measured[:, :3].all(axis=1) & np.isfinite(pred).all(axis=1)
    if full.any():
        Rp, _ = label_to_pose(pred[full])
        Rt, _ = label_to_pose(true[full])
        cos = (np.einsum("nij,nij->n", Rp, Rt) - 1) / 2
        geodesic[full] = np.degrees(np.arccos(np.clip(cos, -1, 1)))
    has_t = measured[:, 3:].all(axis=1) & np.isfinite(pred).all(axis=1)
    translation = np.where(has_t, np.linalg.norm(pred[:, 3:] - true[:, 3:], axis=1), np.nan)
    return {"rotation_sum": rotation_sum, "geodesic": geodesic, "translation": translation}


def _stat(values, fn):
    values = values[np.isfinite(values)]
    return float(fn(values)) if len(values) else None


def success_rate(rotation_sum: np.ndarray, threshold: float) -> float | None:
    """% of frames whose summed rotation error is below ``threshold`` degrees
    (frames without a measured angle, NaN, are left out; no estimate, inf, fails)."""
    rot = rotation_sum[~np.isnan(rotation_sum)]
    return 100.0 * float(np.sum(rot < threshold - TOLERANCE)) / len(rot) if len(rot) else None


def summarise(errors: dict) -> dict:
    """Success rates (% of all frames with a measured angle; a frame without an
    estimate counts as a failure), and median / 90th percentile of the errors."""
    rot = errors["rotation_sum"]
    rot = rot[~np.isnan(rot)]  # frames with at least one measured angle
    n = int(len(rot))
    out = {"frames": n, "estimated": int(np.isfinite(rot).sum())}
    for th in THRESHOLDS:
        out[f"success_{th:g}"] = success_rate(rot, th)
    for name in ("geodesic", "translation"):
        out[f"{name}_median"] = _stat(errors[name], np.median)
        out[f"{name}_p90"] = _stat(errors[name], lambda v: np.percentile(v, 90))
    return out

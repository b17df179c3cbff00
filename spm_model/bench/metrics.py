"""Pose errors and the paper's two success criteria, per-DoF errors and the
accuracy-against-threshold curve.

The paper scores rotations two ways, and the report names them as it does:
- **±5° tolerance** (Table 2: "an error tolerance of ±5 degrees"): every
  rotation angle (rx, ry, rz, each wrapped to (-180, 180]) within 5°,
  inclusive: on a 5° view grid the adjacent view succeeds.
- **sum below 5° (3°)** (Fig. 5, after Hinterstoisser et al. 2007): the sum
  of the absolute angle errors strictly below 5° (3°).
Only label components a dataset measured count (``label_measured``): COIL-100
measures one angle, so its success uses that angle, its geodesic error is
undefined (NaN) and so is its translation error. A frame without an estimate
(NaN prediction) fails every criterion.

Per degree of freedom, the errors are read with spm_data.core.poses's conventions
(:func:`spm_data.core.poses.label_to_view`): azimuth, elevation and in-plane roll of
the camera around the object, the distance to it, and azimuth modulo 180°
(the error left when front and back are confused).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from scipy.spatial.transform import Rotation

from spm_data.core.poses import label_to_pose, label_to_view, pose_to_label, wrap_degrees
from spm_model.methods.smm import PAPER_BINS, pose_bins

SUM_THRESHOLDS = (5.0, 3.0)
TOLERANCE_DEG = 5.0
# Float noise must not decide a criterion: "below 5" means below by more than this,
# "within 5" allows this much over (a 5-degree grid step is 5 up to rounding).
EPS = 1e-6
CURVE_MAX_DEG = 45.0
CURVE_THRESHOLDS = np.linspace(0.0, CURVE_MAX_DEG, 91)  # 0.5-degree steps
VIEW_ERRORS = ("azimuth", "elevation", "roll", "distance", "azimuth_mod180")
AXES = ("x", "y", "z")  # camera axes of the translation error (OpenCV: x right, y down, z forward)


def _view_errors(pred: np.ndarray, true: np.ndarray, ok: np.ndarray) -> dict:
    """(n,) absolute errors per viewing DoF (degrees; distance in metres), NaN where not ``ok``."""
    out = {k: np.full(len(pred), np.nan) for k in VIEW_ERRORS}
    if ok.any():
        vp, vt = label_to_view(pred[ok]), label_to_view(true[ok])
        for k in ("azimuth", "roll"):
            out[k][ok] = np.abs(wrap_degrees(vp[k] - vt[k]))
        out["elevation"][ok] = np.abs(vp["elevation"] - vt["elevation"])
        out["distance"][ok] = np.abs(vp["distance"] - vt["distance"])
        out["azimuth_mod180"][ok] = np.minimum(out["azimuth"][ok], 180.0 - out["azimuth"][ok])
    return out


def pose_errors(pred: np.ndarray, true: np.ndarray, measured: np.ndarray | None = None) -> dict:
    """pred, true (n, 6) labels (degrees, metres); measured (n, 6) bool or None (all).

    Returns (n,) float64 arrays:
    - ``rotation_sum`` / ``rotation_max``: sum / largest of the absolute wrapped
      errors of the measured angles (degrees); NaN when no angle is measured,
      inf when there is no estimate (pred NaN), i.e. a failure;
    - ``geodesic`` (degrees, the angle of R_pred^T R_true) and ``translation``
      (metres, ||t_pred - t_true||): NaN unless every angle (every t component)
      is measured and estimated;
    - ``azimuth``, ``elevation``, ``roll``, ``azimuth_mod180`` (degrees) and
      ``distance`` (metres): see the module docstring; NaN unless the whole
      pose is measured and estimated;
    - ``rotation_measured`` (n,) bool: all three angles measured (the frames the
      geodesic accuracy curve counts, a missing estimate as a miss);
    - ``translation_x``, ``_y``, ``_z`` (metres): absolute error along each camera axis
      (the paper's Figs. 6-7), NaN unless t is measured and estimated."""
    pred = np.array(pred, dtype=np.float64).reshape(-1, 6)
    true = np.asarray(true, dtype=np.float64).reshape(-1, 6)
    measured = np.ones(true.shape, bool) if measured is None else np.asarray(measured, bool).reshape(-1, 6)
    # One rotation has two Euler triples; compare in the canonical one (poses.py's) so a
    # method returning the other is not scored as wrong. Only fully given rows can be converted.
    full_rows = np.isfinite(pred).all(axis=1)
    if full_rows.any():
        pred[full_rows] = pose_to_label(*label_to_pose(pred[full_rows]))
    angle = np.where(measured[:, :3], np.abs(wrap_degrees(pred[:, :3] - true[:, :3])), 0.0)
    has_angle = measured[:, :3].any(axis=1)
    estimated = (np.isfinite(pred) | ~measured).all(axis=1)  # unmeasured components may be left NaN
    errors = {}
    for name, value in (("rotation_sum", angle.sum(axis=1)), ("rotation_max", angle.max(axis=1))):
        value[~estimated] = np.inf  # no estimate: a failure, never a success
        value[~has_angle] = np.nan
        errors[name] = value
    geodesic = np.full(len(pred), np.nan)
    full = measured[:, :3].all(axis=1) & estimated
    if full.any():
        Rp, _ = label_to_pose(pred[full])
        Rt, _ = label_to_pose(true[full])
        # The rotation vector's length: exact near 0, where arccos of the trace loses ~1e-6 degrees.
        geodesic[full] = np.degrees(Rotation.from_matrix(np.einsum("nji,njk->nik", Rp, Rt)).magnitude())
    has_t = measured[:, 3:].all(axis=1) & estimated
    errors["geodesic"] = geodesic
    errors["rotation_measured"] = measured[:, :3].all(axis=1)  # the frames a geodesic curve scores
    errors["translation"] = np.where(has_t, np.linalg.norm(pred[:, 3:] - true[:, 3:], axis=1), np.nan)
    for k, axis in enumerate(AXES):  # Figs. 6-7: per camera axis
        errors[f"translation_{axis}"] = np.where(has_t, np.abs(pred[:, 3 + k] - true[:, 3 + k]), np.nan)
    errors.update(_view_errors(pred, true, full & has_t))
    # SMM's own pose classes (8 azimuth bins of 45°): hit or miss where the rotation is measured.
    hit = (pose_bins(pred) == pose_bins(true)).astype(np.float64)
    errors["pose_class_hit"] = np.where(measured[:, :3].all(axis=1), np.where(estimated, hit, 0.0), np.nan)
    return errors


def success_rate(rotation_sum: np.ndarray, threshold: float) -> float | None:
    """% of frames whose summed rotation error is below ``threshold`` degrees
    (frames without a measured angle, NaN, are left out; no estimate, inf, fails)."""
    rot = rotation_sum[~np.isnan(rotation_sum)]
    return 100.0 * float(np.sum(rot < threshold - EPS)) / len(rot) if len(rot) else None


def tolerance_rate(rotation_max: np.ndarray, tolerance: float = TOLERANCE_DEG) -> float | None:
    """% of frames whose every measured angle is within ``tolerance`` degrees,
    inclusive (NaN frames left out; no estimate, inf, fails)."""
    rot = rotation_max[~np.isnan(rotation_max)]
    return 100.0 * float(np.sum(rot <= tolerance + EPS)) / len(rot) if len(rot) else None


def accuracy_curve(geodesic: np.ndarray, frames: int, thresholds=CURVE_THRESHOLDS) -> np.ndarray:
    """% of ``frames`` (every scored frame; a frame without an estimate or with
    NaN geodesic error counts as a miss) whose geodesic error is <= each threshold."""
    g = np.sort(geodesic[np.isfinite(geodesic)])
    return 100.0 * np.searchsorted(g, np.asarray(thresholds) + EPS, side="right") / max(frames, 1)


def curve_auc(curve: np.ndarray, thresholds=CURVE_THRESHOLDS) -> float:
    """Area under an accuracy curve (in %) over [0, max threshold], normalised to 0-100."""
    t = np.asarray(thresholds, dtype=np.float64)
    c = np.asarray(curve, dtype=np.float64)
    return float(np.sum((c[1:] + c[:-1]) / 2 * np.diff(t)) / (t[-1] - t[0]))


def _stat(values, fn, scale=1.0):
    values = values[np.isfinite(values)]
    return float(fn(values)) * scale if len(values) else None


def _p90(values):
    return np.percentile(values, 90)


@dataclass(frozen=True)
class Metric:
    """One figure of a summary entry: ``key`` (dotted for a nested one), how it is computed
    from the per-frame errors, its column in results.md, in the terminal's table
    (None: not shown there) and what it means (docs/results-schema.md is made from these)."""

    key: str
    compute: Callable
    header: str
    meaning: str
    terminal: str | None = None
    digits: int = 1


def _sym(name, fn):
    return lambda e: fn(e[name]) if name in e else None


def coverage(rotation_max: np.ndarray) -> float | None:
    """% of the scored frames (a measured angle: not NaN) with an estimate (finite)."""
    scored = rotation_max[~np.isnan(rotation_max)]
    return 100.0 * float(np.isfinite(scored).sum()) / len(scored) if len(scored) else None


METRICS = (
    Metric("coverage", lambda e: coverage(e["rotation_max"]), "Coverage %",
           "% of the scored frames the method gave an estimate for (`estimated` / `frames`); every other "
           "figure counts a frame without one as a failure (medians: over the frames with one)", "cov %"),
    Metric("success_tol5", lambda e: tolerance_rate(e["rotation_max"]), "±5° %",
           "% with every measured rotation angle (rx, ry, rz of the label, wrapped) within 5°, inclusive: the "
           "paper's Table 2 \"error tolerance of ±5 degrees\"", "±5° %"),
    Metric("success_sum5", lambda e: success_rate(e["rotation_sum"], 5.0), "sum<5° %",
           "% whose summed absolute angle errors are below 5°: the paper's Fig. 5(a) criterion (after "
           "Hinterstoisser et al. 2007)", "sum<5 %"),
    Metric("success_sum3", lambda e: success_rate(e["rotation_sum"], 3.0), "sum<3° %",
           "the same below 3°: Fig. 5(b)"),
    Metric("auc_45", lambda e: (curve_auc(accuracy_curve(e["geodesic"], int(e["rotation_measured"].sum())))
                                if e["rotation_measured"].any() else None), "AUC 45°",
           "area under the accuracy-against-geodesic-threshold curve over 0–45°, normalised to 0–100", "AUC45"),
    Metric("geodesic_median_deg", lambda e: _stat(e["geodesic"], np.median), "Geodesic median °",
           "median of the rotation's geodesic error", "geo med"),
    Metric("geodesic_p90_deg", lambda e: _stat(e["geodesic"], _p90), "p90 °",
           "90th percentile of the rotation's geodesic error"),
    Metric("pose_class_accuracy", lambda e: _stat(e["pose_class_hit"], np.mean, 100.0), "Pose class %",
           f"% whose azimuth falls in the true azimuth's class of SMM's {PAPER_BINS} pose classes "
           f"({360 // PAPER_BINS}° bins centred on 0°, {360 // PAPER_BINS}°, …; Mei et al. 2011): SMM's own criterion"),
    Metric("success_tol5_sym", _sym("rotation_max_sym", tolerance_rate), "±5° sym. %",
           "`success_tol5` against the symmetric equivalent of the truth nearest the estimate, under the "
           "symmetries the spec or generator declares (bench/symmetry_errors.py); `null` where no mesh is known"),
    Metric("geodesic_median_sym_deg", _sym("geodesic_sym", lambda v: _stat(v, np.median)), "Geodesic sym. °",
           "median geodesic error up to the declared symmetries"),
    Metric("translation_median_mm", lambda e: _stat(e["translation"], np.median, 1000.0), "t median mm",
           "median of ‖t_pred − t_true‖"),
    Metric("translation_p90_mm", lambda e: _stat(e["translation"], _p90, 1000.0), "t p90 mm",
           "90th percentile of ‖t_pred − t_true‖"),
    *(Metric(f"translation_axis_median_mm.{a}", (lambda a: lambda e: _stat(e[f"translation_{a}"], np.median,
                                                                              1000.0))(a),
             f"t{a} mm", f"median absolute translation error along the camera's {a} axis (Figs. 6–7)")
      for a in AXES),
    *(Metric(f"median_error.{k}_deg", (lambda k: lambda e: _stat(e[k], np.median))(k), label,
             f"median absolute error of the {what} (spm_data/core/poses.py's `label_to_view`)", term)
      for k, label, what, term in (("azimuth", "Azimuth °", "camera's azimuth around the object", None),
                                   ("azimuth_mod180", "Az. mod 180 °", "azimuth, front/back confusions forgiven",
                                    None),
                                   ("elevation", "Elevation °", "camera's elevation", "elev °"),
                                   ("roll", "Roll °", "in-plane roll", None))),
    Metric("median_error.distance_mm", lambda e: _stat(e["distance"], np.median, 1000.0), "Distance mm",
           "median absolute error of the camera's distance to the object origin", "dist mm"),
)


Z95 = 1.959963984540054  # the normal quantile of a two-sided 95% interval
# The success rates (% of frames) that carry a 95% Wilson interval, and the per-frame array whose
# non-NaN entries are the frames each is a rate of.
RATES = {"success_tol5": "rotation_max", "success_sum5": "rotation_sum", "success_sum3": "rotation_sum",
         "success_tol5_sym": "rotation_max_sym", "pose_class_accuracy": "pose_class_hit"}


def wilson_interval(rate: float | None, n: float) -> tuple[float, float] | None:
    """The 95% Wilson score interval (low, high), in %, of a success rate ``rate`` (%) over ``n``
    frames (n may be a mean over runs, so not whole); None without a rate or frames.

    Wilson's, not the normal approximation: it stays inside 0-100% and is honest at 0% or 100%
    and with few frames (Brown, Cai & DasGupta 2001)."""
    if rate is None or not n or n <= 0:
        return None
    p, z2 = rate / 100.0, Z95 * Z95
    centre = (p + z2 / (2 * n)) / (1 + z2 / n)
    half = Z95 * np.sqrt(p * (1 - p) / n + z2 / (4 * n * n)) / (1 + z2 / n)
    return 100.0 * max(0.0, centre - half), 100.0 * min(1.0, centre + half)


def intervals(entry: dict, counts: dict) -> dict:
    """``ci95`` of a summary entry: {rate key: {"low", "high", "n"}} (%, %, frames) for every
    RATES key ``entry`` has a value for; ``counts`` gives each key's frames."""
    out = {}
    for key in RATES:
        bounds = wilson_interval(entry.get(key), counts.get(key) or 0)
        if bounds is not None:
            out[key] = {"low": bounds[0], "high": bounds[1], "n": counts[key]}
    return out


def refresh_intervals(entry: dict) -> dict:
    """``entry`` with its ``ci95`` recomputed from its (mean) rates and (mean) counts: the
    interval of a mean over runs is the interval of one run's frames at that mean."""
    if entry.get("ci95"):
        entry["ci95"] = intervals(entry, {k: v["n"] for k, v in entry["ci95"].items()})
    return entry


def rate_counts(errors: dict) -> dict:
    """{rate key: frames it is a rate of} from per-frame errors (pose_errors' keys)."""
    return {k: int((~np.isnan(errors[a])).sum()) for k, a in RATES.items() if a in errors}


def metric_value(entry: dict, key: str):
    """A metric's value in a summary entry (dotted keys reach into nested dicts); None if absent."""
    for part in key.split("."):
        entry = entry.get(part) if isinstance(entry, dict) else None
    return entry


def summarise(errors: dict) -> dict:
    """``frames`` (with a measured angle), ``estimated`` (of those, with an estimate; a
    missing one fails every criterion), every METRICS entry and, when ``errors`` has the
    keys of :func:`spm_model.bench.surface_metrics.surface_errors`, ``surface``
    (docs/results-schema.md lists every key)."""
    rot_max = errors["rotation_max"]
    scored = ~np.isnan(rot_max)
    out = {"frames": int(scored.sum()), "estimated": int(np.isfinite(rot_max[scored]).sum())}
    for metric in METRICS:
        *parents, leaf = metric.key.split(".")
        target = out
        for part in parents:
            target = target.setdefault(part, {})
        target[leaf] = metric.compute(errors)
    out["ci95"] = intervals(out, rate_counts(errors))
    if "add" in errors:
        from spm_model.bench.surface_metrics import summarise_surface

        out["surface"] = summarise_surface(errors)
    return out

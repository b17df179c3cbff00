"""N3M, online: matches of a test image's keypoints to the model's 3-D points, the
multi-level validation, and the pose.

1. Photometric level (:func:`match`): a keypoint matches the nearest stored descriptor
   if that one is nearer than ``ratio`` times the nearest descriptor of a point
   elsewhere (copies of the same 3-D point are not rivals); one keypoint per point.
2. Marker level (:func:`marker_hypotheses`): every N3M with at least 4 matched points
   gives a pose (SQPnP) that must reproject all of them within ``tol`` pixels, in
   front of the camera; a marker failing this is discarded, not repaired.
3. Global level (:func:`best_pose`): each surviving pose is scored by the matches of
   the whole model it reprojects within ``tol`` (its inliers); the best is refined
   (Levenberg-Marquardt on its inliers, twice) and accepted with at least
   ``min_inliers`` inliers.
Not in the paper: without a valid marker, PnP with RANSAC over all matches may propose
the pose instead (``fallback``, off in the benchmark's N3M), under the same global test
(:func:`ransac_pose`); alone, that is the SIFT + PnP baseline (sift_pnp.py).
Pixels are OpenCV centres of the image as given; 3-D points metres in the object frame;
poses ``R`` (3, 3), ``t`` (3,) map object to camera (spm_data/core/poses.py).
"""

from __future__ import annotations

import cv2
import numpy as np

from spm_model.methods.n3m_points import knn

MIN_MARKER = 4           # matched points a marker needs for its own pose
NEIGHBOURS = 8           # stored descriptors a keypoint looks at for its rival
RANSAC_ITERATIONS = 300


def match(index, desc_xyz, desc_point, queries, *, ratio: float, same_radius: float,
          checks: int = 32) -> tuple[np.ndarray, np.ndarray]:
    """Level 1: keypoint descriptors ``queries`` (n, 128) against the stored ones
    (``index`` over rows whose 3-D points are ``desc_xyz`` (d, 3), ids ``desc_point`` (d,)).
    Returns ``keypoint`` (m,) and ``point`` (m,) int: the kept matches, one per point
    (the nearest keypoint wins)."""
    idx, dist = knn(index, queries, min(NEIGHBOURS, len(desc_point)), checks=checks)
    if len(idx) == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    valid = idx >= 0
    first = np.where(valid[:, 0], idx[:, 0], 0)
    far = np.linalg.norm(desc_xyz[np.maximum(idx, 0)] - desc_xyz[first][:, None, :], axis=2) > same_radius
    rival = np.where(far & valid, dist, np.inf).min(axis=1)
    ok = valid[:, 0] & (dist[:, 0] < ratio * rival)
    keypoint = np.flatnonzero(ok)
    if len(keypoint) == 0:
        return keypoint, np.zeros(0, np.int64)
    point = desc_point[first[keypoint]]
    order = np.lexsort((dist[keypoint, 0], point))          # by point, nearest first
    keypoint, point = keypoint[order], point[order]
    first_of_point = np.r_[True, point[1:] != point[:-1]]
    return keypoint[first_of_point], point[first_of_point]


def reprojection_errors(xyz, uv, K, rvec, tvec) -> np.ndarray:
    """(n,) pixel distances between ``uv`` (n, 2) and the projections of ``xyz`` (n, 3);
    inf for points behind the camera."""
    xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
    R, _ = cv2.Rodrigues(np.asarray(rvec, dtype=np.float64))
    cam = xyz @ R.T + np.asarray(tvec, dtype=np.float64).reshape(3)
    with np.errstate(divide="ignore", invalid="ignore"):
        proj = (cam @ np.asarray(K, dtype=np.float64).T)[:, :2] / cam[:, 2:3]
    err = np.linalg.norm(proj - np.asarray(uv, dtype=np.float64).reshape(-1, 2), axis=1)
    return np.where(cam[:, 2] > 0, err, np.inf)


def marker_hypotheses(markers, matched_point, xyz, uv, K, *, tol: float) -> list:
    """Level 2: poses of the N3Ms ``markers`` (M, s) int point ids that at least
    MIN_MARKER of whose points are matched (``matched_point`` (m,) ids of the matches
    ``xyz`` (m, 3) -> ``uv`` (m, 2)) and whose own pose reprojects all of them within
    ``tol`` pixels. Returns a list of (rvec, tvec)."""
    if len(matched_point) < MIN_MARKER or len(markers) == 0:
        return []
    rows, found = _marker_rows(np.asarray(markers, dtype=np.int64), np.asarray(matched_point, dtype=np.int64))
    out = []
    for j in np.flatnonzero(found.sum(axis=1) >= MIN_MARKER):
        rows_j = rows[j][found[j]]
        ok, rvec, tvec = cv2.solvePnP(xyz[rows_j], uv[rows_j], K, None, flags=cv2.SOLVEPNP_SQPNP)
        if ok and np.all(reprojection_errors(xyz[rows_j], uv[rows_j], K, rvec, tvec) <= tol):
            out.append((rvec, tvec))
    return out


def _marker_rows(markers, matched_point):
    """Where each marker's points are among the matches: ``rows`` (M, s) int match row
    (the last match of that point) and ``found`` (M, s) bool. One sorted search for all
    markers (a Python loop over them cost a millisecond an image)."""
    ids, first_reversed = np.unique(matched_point[::-1], return_index=True)
    last = len(matched_point) - 1 - first_reversed
    at = np.minimum(np.searchsorted(ids, markers), len(ids) - 1)
    found = ids[at] == markers
    return np.where(found, last[at], -1), found


def ransac_hypothesis(xyz, uv, K, *, tol: float) -> list:
    """PnP with RANSAC (AP3P on minimal samples) over all matches: [(rvec, tvec)] or [].
    Repeatable: OpenCV's RANSAC draws its samples from a generator of its own with a
    fixed seed, not from the thread's (cv2.setRNGSeed has no effect on it)."""
    if len(xyz) < MIN_MARKER:
        return []
    ok, rvec, tvec, _ = cv2.solvePnPRansac(xyz, uv, K, None, iterationsCount=RANSAC_ITERATIONS,
                                           reprojectionError=float(tol), confidence=0.999,
                                           flags=cv2.SOLVEPNP_AP3P)
    return [(rvec, tvec)] if ok else []


def refine(xyz, uv, K, rvec, tvec, *, tol: float, rounds: int = 2):
    """The pose refined by Levenberg-Marquardt on its inliers (error <= ``tol``), ``rounds``
    times; returns (rvec, tvec, inliers (n,) bool)."""
    rvec, tvec = np.array(rvec, dtype=np.float64).reshape(3, 1), np.array(tvec, dtype=np.float64).reshape(3, 1)
    inliers = reprojection_errors(xyz, uv, K, rvec, tvec) <= tol
    for _ in range(rounds):
        if inliers.sum() < MIN_MARKER:
            break
        rvec, tvec = cv2.solvePnPRefineLM(xyz[inliers], uv[inliers], K, None, rvec, tvec)
        inliers = reprojection_errors(xyz, uv, K, rvec, tvec) <= tol
    return rvec, tvec, inliers


def best_pose(hypotheses, xyz, uv, K, *, tol: float, min_inliers: int):
    """Level 3: the hypothesis with the most inliers over all matches, refined
    (:func:`refine`). Returns (R (3, 3), t (3,), inliers count) or None when the best
    has fewer than ``min_inliers`` inliers."""
    best, count = None, -1
    for rvec, tvec in hypotheses:
        n = int((reprojection_errors(xyz, uv, K, rvec, tvec) <= tol).sum())
        if n > count:
            best, count = (rvec, tvec), n
    if best is None or count < min_inliers:
        return None
    rvec, tvec, inliers = refine(xyz, uv, K, *best, tol=tol)
    if inliers.sum() < min_inliers:
        return None
    R, _ = cv2.Rodrigues(rvec)
    return R, tvec.reshape(3), int(inliers.sum())


def estimate(markers, matched_point, xyz, uv, K, *, tol: float, min_inliers: int, fallback: bool):
    """The pose from matches ``xyz`` (m, 3) -> ``uv`` (m, 2), ``matched_point`` (m,) their
    point ids: markers first, then, only if none passes and ``fallback`` (not in the
    paper), :func:`ransac_pose`. Returns (R, t, inliers, source) with source "n3m" or
    "ransac", or None."""
    xyz, uv, K = _as_float(xyz, uv, K)
    found = best_pose(marker_hypotheses(markers, matched_point, xyz, uv, K, tol=tol), xyz, uv, K,
                      tol=tol, min_inliers=min_inliers)
    if found is not None:
        return (*found, "n3m")
    return ransac_pose(xyz, uv, K, tol=tol, min_inliers=min_inliers) if fallback else None


def ransac_pose(xyz, uv, K, *, tol: float, min_inliers: int):
    """No markers: PnP with RANSAC over all matches ``xyz`` (m, 3) -> ``uv`` (m, 2)
    (:func:`ransac_hypothesis`) proposes, the global level (:func:`best_pose`) accepts.
    N3M's fallback, and the whole of SIFT + PnP (sift_pnp.py). Returns (R, t, inliers,
    "ransac") or None."""
    xyz, uv, K = _as_float(xyz, uv, K)
    if len(xyz) < min_inliers:   # fewer matches than the inliers a pose needs
        return None
    found = best_pose(ransac_hypothesis(xyz, uv, K, tol=tol), xyz, uv, K, tol=tol,
                      min_inliers=min_inliers)
    return None if found is None else (*found, "ransac")


def _as_float(xyz, uv, K):
    """(xyz (m, 3), uv (m, 2), K (3, 3)) as contiguous float64 (OpenCV's PnP wants them so)."""
    return (np.ascontiguousarray(xyz, dtype=np.float64).reshape(-1, 3),
            np.ascontiguousarray(uv, dtype=np.float64).reshape(-1, 2), np.asarray(K, dtype=np.float64))

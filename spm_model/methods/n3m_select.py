"""N3M, offline stage 2: Natural 3D Markers chosen from one object's scored 3-D points.

An N3M is a small set of ``size`` points (at least 4) that is
- photometrically distinctive: its points are stable ones (quality > 0: repeatable and
  distinctive, spm_model/methods/n3m_points.py), grown around a seed in quality order;
- local: every point within ``radius`` metres of the seed, and detected together with
  it in at least half of the seed's views, so the whole marker tends to be found (and
  to escape an occluder) together;
- geometrically sound: no two points closer than ``min_gap`` metres and not coplanar
  (:func:`flatness` >= ``min_relief``), so its pose is neither degenerate nor ambiguous;
- well distributed: markers are picked greedily until every training view has
  ``per_view`` of them detected (at least 4 of their points found in that view),
  preferring good markers that cover views still short; no two markers share more
  than one point.
Arrays: positions (p, 3) metres in the object frame; detected (p, v) bool: whether a
point was found in each of the object's training views.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

MIN_SEEN = 4           # points of a marker a view must see to count it (a PnP needs 4)
COVISIBLE = 0.5        # a member must be detected in at least this fraction of the seed's views
MAX_NEIGHBOURS = 24    # best-quality neighbours a seed tries


def flatness(points) -> float:
    """How far ``points`` (k, 3) are from coplanar: the smallest singular value of the
    centred set over the largest, in [0, 1] (0: coplanar or collinear; 1: an isotropic
    set, e.g. a regular tetrahedron's corners); 0 for fewer than 4 points."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if len(points) < 4:
        return 0.0
    s = np.linalg.svd(points - points.mean(axis=0), compute_uv=False)
    return float(s[2] / s[0]) if s[0] > 0 else 0.0


def grow(seed: int, positions, quality, detected, *, size: int, radius: float, min_gap: float,
         min_relief: float, tree=None):
    """The marker grown around point ``seed``: neighbours within ``radius`` of it that
    are stable and co-detected (``detected`` (p, v), COVISIBLE); each step adds the best
    one (in quality order) that keeps every pair at least ``min_gap`` apart and the set
    non-collinear, then non-coplanar (:func:`flatness` >= ``min_relief``). Returns
    (size,) int point indices, or None if no such set exists among them."""
    tree = cKDTree(positions) if tree is None else tree
    near = np.asarray(tree.query_ball_point(positions[seed], r=radius), dtype=np.int64)
    near = near[(near != seed) & (quality[near] > 0)]
    seen = detected[seed]
    shared = (detected[near] & seen).sum(axis=1)
    near = near[shared >= COVISIBLE * max(1, seen.sum())]
    near = near[np.argsort(-quality[near], kind="stable")][:MAX_NEIGHBOURS]
    chosen = [seed]
    while len(chosen) < size:
        fits = np.flatnonzero(_fits(positions, chosen, near, min_gap, min_relief))
        if len(fits) == 0:
            return None
        chosen.append(int(near[fits[0]]))
        near = np.delete(near, fits[0])
    return np.array(chosen, dtype=np.int64)


def _fits(positions, chosen: list, near, min_gap: float, min_relief: float) -> np.ndarray:
    """(len(near),) bool: whether each of the points ``near`` may join ``chosen``: at
    least ``min_gap`` from each, and the set stays non-collinear (3 points: second over
    first singular value) or non-coplanar (4 and more: :func:`flatness`) by ``min_relief``."""
    base = positions[chosen]
    trial = np.concatenate([np.broadcast_to(base, (len(near), *base.shape)), positions[near][:, None]], axis=1)
    ok = np.linalg.norm(base[None] - positions[near][:, None], axis=2).min(axis=1) >= min_gap
    if trial.shape[1] < 3:
        return ok
    s = np.linalg.svd(trial - trial.mean(axis=1, keepdims=True), compute_uv=False)
    which = 1 if trial.shape[1] == 3 else 2
    return ok & (s[:, which] >= min_relief * np.maximum(s[:, 0], 1e-300)) & (s[:, 0] > 0)


def candidates(positions, quality, detected, *, size: int, radius: float, min_gap: float,
               min_relief: float) -> np.ndarray:
    """Every marker :func:`grow` finds, one per stable seed: (c, size) int point indices."""
    positions = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    quality = np.asarray(quality, dtype=np.float64)
    if len(positions) < size:
        return np.zeros((0, size), dtype=np.int64)
    tree = cKDTree(positions)
    found = []
    for seed in np.flatnonzero(quality > 0):
        marker = grow(int(seed), positions, quality, detected, size=size, radius=radius,
                      min_gap=min_gap, min_relief=min_relief, tree=tree)
        if marker is not None:
            found.append(marker)
    return np.array(found, dtype=np.int64).reshape(-1, size)


def choose(markers, quality, detected, *, per_view: int, max_markers: int) -> np.ndarray:
    """The markers kept, greedily: each step takes the marker with the largest
    (mean member quality) x (views it covers that see fewer than ``per_view`` chosen
    markers yet), skipping any that shares more than one point with a chosen one,
    until no marker adds coverage or ``max_markers`` are chosen. A view covers a marker
    when at least MIN_SEEN of its points were detected in it (``detected`` (p, v)).
    Returns (m,) int indices into ``markers``."""
    markers = np.asarray(markers, dtype=np.int64)
    if len(markers) == 0:
        return np.zeros(0, dtype=np.int64)
    score = np.asarray(quality, dtype=np.float64)[markers].mean(axis=1)
    seen = detected[markers].sum(axis=1) >= MIN_SEEN            # (c, v)
    need = np.full(seen.shape[1], per_view, dtype=np.int64)
    open_ = np.ones(len(markers), dtype=bool)
    chosen = []
    while len(chosen) < max_markers:
        gain = (seen & (need > 0)).sum(axis=1) * score * open_
        best = int(np.argmax(gain))
        if gain[best] <= 0:
            break
        chosen.append(best)
        need -= seen[best]
        shared = (markers[:, :, None] == markers[best][None, None, :]).any(axis=2).sum(axis=1)
        open_ &= shared <= 1
    return np.array(chosen, dtype=np.int64)


def select_markers(positions, quality, detected, *, size: int, radius: float, min_gap: float,
                   min_relief: float, per_view: int, max_markers: int) -> np.ndarray:
    """One object's N3Ms: (m, size) int indices into ``positions`` (p, 3)
    (:func:`candidates`, then :func:`choose`)."""
    found = candidates(positions, quality, detected, size=size, radius=radius, min_gap=min_gap,
                       min_relief=min_relief)
    return found[choose(found, quality, detected, per_view=per_view, max_markers=max_markers)]

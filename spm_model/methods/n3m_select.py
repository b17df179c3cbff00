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
    near = _neighbours(seed, positions, quality, detected, radius, cKDTree(positions) if tree is None else tree)
    chosen = [seed]
    while len(chosen) < size:
        fits = np.flatnonzero(_fits(positions, chosen, near, min_gap, min_relief))
        if len(fits) == 0:
            return None
        chosen.append(int(near[fits[0]]))
        near = np.delete(near, fits[0])
    return np.array(chosen, dtype=np.int64)


def _neighbours(seed: int, positions, quality, detected, radius: float, tree) -> np.ndarray:
    """The points a marker may grow with around ``seed``, best first (:func:`grow`): stable ones within
    ``radius``, co-detected (COVISIBLE), in quality order (ties in the tree query's order), at most MAX_NEIGHBOURS."""
    near = np.asarray(tree.query_ball_point(positions[seed], r=radius), dtype=np.int64)
    near = near[(near != seed) & (quality[near] > 0)]
    seen = detected[seed]
    shared = (detected[near] & seen).sum(axis=1)
    near = near[shared >= COVISIBLE * max(1, seen.sum())]
    return near[np.argsort(-quality[near], kind="stable")][:MAX_NEIGHBOURS]


def _fits(positions, chosen: list, near, min_gap: float, min_relief: float) -> np.ndarray:
    """(len(near),) bool: whether each of the points ``near`` may join ``chosen``: at
    least ``min_gap`` from each, and the set stays non-collinear (3 points: second over
    first singular value) or non-coplanar (4 and more: :func:`flatness`) by ``min_relief``."""
    base = positions[chosen]
    ok = np.linalg.norm(base[None] - positions[near][:, None], axis=2).min(axis=1) >= min_gap
    if len(chosen) < 2:
        return ok
    return ok & _not_flat(np.broadcast_to(base, (len(near), *base.shape)), positions[near], min_relief)


def candidates(positions, quality, detected, *, size: int, radius: float, min_gap: float,
               min_relief: float) -> np.ndarray:
    """Every marker :func:`grow` finds, one per stable seed, in seed order: (c, size) int point indices.
    Every seed grows at once, a step at a time (one batch of array work per step instead of one
    per seed and step: the loop over seeds was a third of N3M's training time); each step's choice
    is grow's, computed from the same numbers, so the markers are grow's, bit for bit
    (tests/model/methods/test_n3m_select.py compares them)."""
    positions = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    quality = np.asarray(quality, dtype=np.float64)
    seeds = np.flatnonzero(quality > 0)
    if len(positions) < size or not len(seeds):
        return np.zeros((0, size), dtype=np.int64)
    near = _neighbour_table(seeds, positions, quality, detected, radius)
    valid, near = near >= 0, np.maximum(near, 0)
    chosen = seeds[:, None]
    gap = np.where(valid, np.linalg.norm(positions[near] - positions[seeds][:, None], axis=2), -np.inf)
    for _ in range(size - 1):
        pick = _first_fits(positions, chosen, near, valid & (gap >= min_gap), min_relief)
        keep = pick >= 0
        chosen, near, valid, gap, pick = chosen[keep], near[keep], valid[keep], gap[keep], pick[keep]
        rows = np.arange(len(pick))
        added = near[rows, pick]
        chosen = np.concatenate([chosen, added[:, None]], axis=1)
        valid[rows, pick] = False
        step = np.linalg.norm(positions[near] - positions[added][:, None], axis=2)
        gap = np.where(valid, np.minimum(gap, step), -np.inf)
    return chosen.astype(np.int64).reshape(-1, size)


def _neighbour_table(seeds, positions, quality, detected, radius: float) -> np.ndarray:
    """(s, MAX_NEIGHBOURS) int: row i holds :func:`_neighbours` of ``seeds[i]`` in its order, -1 after
    them; every seed at once (one tree query, unsorted as grow's is, then one stable sort)."""
    lists = cKDTree(positions).query_ball_point(positions[seeds], r=radius, return_sorted=False)
    counts = np.array([len(found) for found in lists], dtype=np.int64)
    near = np.concatenate([np.asarray(found, dtype=np.int64) for found in lists])
    row = np.repeat(np.arange(len(seeds)), counts)
    seen = detected[seeds]
    shared = (detected[near] & seen[row]).sum(axis=1)
    keep = (near != seeds[row]) & (quality[near] > 0) & (shared >= COVISIBLE * np.maximum(1, seen.sum(axis=1))[row])
    near, row = near[keep], row[keep]
    order = np.lexsort((-quality[near], row))   # by seed, best first, ties in the query's order
    near, row = near[order], row[order]
    rank = np.arange(len(row)) - np.searchsorted(row, row)
    table = np.full((len(seeds), MAX_NEIGHBOURS), -1, dtype=np.int64)
    first = rank < MAX_NEIGHBOURS
    table[row[first], rank[first]] = near[first]
    return table


def _first_fits(positions, chosen, near, spaced, min_relief: float, batch: int = 4) -> np.ndarray:
    """Per row of ``chosen`` (s, k) the column of ``near`` (s, m) holding the first point that may
    join it (:func:`_fits`: ``spaced`` (s, m), and not flat by ``min_relief``), -1 where none may.
    The singular values are computed for ``batch`` spaced points of each row at a time, in order,
    until one fits (usually the first batch)."""
    first = np.full(len(near), -1, dtype=np.int64)
    if chosen.shape[1] < 2:   # a set of two points is never flat
        some = spaced.any(axis=1)
        first[some] = np.argmax(spaced[some], axis=1)
        return first
    rank = np.cumsum(spaced, axis=1) - 1
    left = rank.max(axis=1, initial=-1)
    pending = left >= 0
    start = 0
    while pending.any():
        rows, cols = np.nonzero(spaced & (rank >= start) & (rank < start + batch) & pending[:, None])
        fits = _not_flat(positions[chosen[rows]], positions[near[rows, cols]], min_relief)
        hit, at = np.unique(rows[fits], return_index=True)   # row-major: each row's first fit
        first[hit] = cols[fits][at]
        pending[hit] = False
        start += batch
        pending &= left >= start
    return first


def _not_flat(base, added, min_relief: float) -> np.ndarray:
    """(n,) bool: whether each set ``base`` (n, k, 3) plus its point ``added`` (n, 3) is
    non-collinear (3 points: second over first singular value) or non-coplanar (4 and more:
    :func:`flatness`) by ``min_relief``."""
    trial = np.concatenate([base, added[:, None]], axis=1)
    s = np.linalg.svd(trial - trial.mean(axis=1, keepdims=True), compute_uv=False)
    which = 1 if trial.shape[1] == 3 else 2
    return (s[:, which] >= min_relief * np.maximum(s[:, 0], 1e-300)) & (s[:, 0] > 0)


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

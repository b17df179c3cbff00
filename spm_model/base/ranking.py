"""The k smallest entries of each row, exactly as a stable sort ranks them, in O(m) a row."""

from __future__ import annotations

import numpy as np


def smallest_k(d, k: int) -> np.ndarray:
    """Column indices of each row's ``k`` smallest values: ``d`` (n, m) -> (n, min(k, m))
    int64, ascending, ties by column, NaN last: the same array as
    ``np.argsort(d, axis=1, kind="stable")[:, :k]``.

    A full sort costs O(m log m) a row; when k is much smaller than m, a partition finds
    each row's k-th smallest value and only the entries up to it (ties included) are
    sorted. Rows with fewer than k values that are not NaN are sorted whole."""
    if int(k) < 0:
        raise ValueError(f"smallest_k: k must be 0 or more, got {k}")
    d = np.asarray(d)
    n, m = d.shape
    k = min(int(k), m)
    if k == 0 or 8 * k >= m:
        return np.argsort(d, axis=1, kind="stable")[:, :k].astype(np.int64, copy=False)
    kth = np.take_along_axis(d, np.argpartition(d, k - 1, axis=1)[:, k - 1:k], axis=1)
    candidate = d <= kth                               # False everywhere when kth is NaN
    counts = candidate.sum(axis=1)
    rows, cols = np.nonzero(candidate)                 # row by row, columns ascending
    order = np.lexsort((d[rows, cols], rows))          # stable: ties keep column order
    starts = np.cumsum(counts) - counts
    short = counts < k
    take = np.where(short, 0, starts)[:, None] + np.arange(k)[None]
    out = cols[order][np.minimum(take, max(len(cols) - 1, 0))] if len(cols) else np.zeros((n, k), np.int64)
    if short.any():
        out[short] = np.argsort(d[short], axis=1, kind="stable")[:, :k]
    return out.astype(np.int64, copy=False)

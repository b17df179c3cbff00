"""Sparse re-projection (paper §2.3, Eq. 5), read as Sparsity Preserving Projections
(Qiao, Chen & Tan 2010, the paper's reference for it; see docs/method.md).

Eq. 5: every training vector m_i is written as an affine combination of the
others with the smallest l1 norm: ``min ||r_i||_1 s.t. m_i = M r_i, 1^T r_i = 1,
r_ii = 0``. The weights S = [r_1 ... r_t] define the projection: the directions
w maximising ``w^T M S_b M^T w / w^T M M^T w`` with ``S_b = S + S^T - S^T S``,
a generalised eigenproblem; a query vector is projected with the same W.

Solvers: ``exact`` solves each l1 problem as a linear programme (HiGHS) over all
other samples (small sets, and the reference); ``knn`` solves the same programme
over the k nearest neighbours only, which is what scales.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import linprog


class SparseError(ValueError):
    """An l1 problem had no solution (too few or degenerate samples)."""


def l1_weights(target: np.ndarray, dictionary: np.ndarray) -> np.ndarray:
    """min ||r||_1 s.t. dictionary @ r = target, sum(r) = 1. dictionary (m, n) -> r (n,)."""
    m, n = dictionary.shape
    A = np.vstack([dictionary, np.ones((1, n))])
    b = np.concatenate([target, [1.0]])
    # r = u - v with u, v >= 0; minimise sum(u + v).
    res = linprog(np.ones(2 * n), A_eq=np.hstack([A, -A]), b_eq=b, bounds=(0, None), method="highs")
    if res.status != 0:
        # Not exactly representable: the least-l1 weights of the nearest representable point.
        lsq = np.linalg.lstsq(A, b, rcond=None)[0]
        res = linprog(np.ones(2 * n), A_eq=np.hstack([A, -A]), b_eq=A @ lsq, bounds=(0, None), method="highs")
        if res.status != 0:
            raise SparseError(f"l1 problem unsolvable ({res.message})")
    return res.x[:n] - res.x[n:]


def sparse_weights(M: np.ndarray, method: str = "exact", k: int = 64) -> np.ndarray:
    """S (t, t): column i holds Eq. 5's weights of sample i (M is (m, t), samples in columns)."""
    m, t = M.shape
    if t < 3:
        raise SparseError(f"need at least 3 samples, got {t}")
    S = np.zeros((t, t))
    if method == "knn":
        d2 = ((M.T[:, None, :] - M.T[None, :, :]) ** 2).sum(axis=2) if t <= 4096 else None
    for i in range(t):
        if method == "exact":
            others = np.delete(np.arange(t), i)
        elif method == "knn":
            dist = d2[i] if d2 is not None else ((M.T - M[:, i]) ** 2).sum(axis=1)
            dist = dist.copy()
            dist[i] = np.inf
            others = np.argsort(dist, kind="stable")[: min(k, t - 1)]
        else:
            raise SparseError(f"method must be 'exact' or 'knn', got {method!r}")
        S[others, i] = l1_weights(M[:, i], M[:, others])
    return S


@dataclass(frozen=True)
class SparseProjection:
    """W (m, d): project a vector x (m,) as W.T @ x."""

    W: np.ndarray

    def transform(self, X: np.ndarray) -> np.ndarray:
        """(n, m) -> (n, d)."""
        return np.asarray(X, dtype=np.float64) @ self.W


def fit_projection(X: np.ndarray, dims: int | None = None, method: str = "exact", k: int = 64,
                   ridge: float = 1e-8) -> SparseProjection:
    """SPP from (t, m) training vectors: the top ``dims`` (default m) generalised eigenvectors."""
    from scipy.linalg import eigh

    X = np.asarray(X, dtype=np.float64)
    M = X.T
    S = sparse_weights(M, method=method, k=k)
    Sb = S + S.T - S.T @ S
    left = M @ Sb @ M.T
    right = M @ M.T + ridge * np.trace(M @ M.T) * np.eye(M.shape[0])
    values, vectors = eigh((left + left.T) / 2, right)
    order = np.argsort(values)[::-1][: dims or M.shape[0]]
    W = vectors[:, order]
    W /= np.linalg.norm(W, axis=0, keepdims=True)
    # A fixed sign per direction, so refits give the same projection.
    W *= np.sign(W[np.argmax(np.abs(W), axis=0), np.arange(W.shape[1])])
    return SparseProjection(W=W)

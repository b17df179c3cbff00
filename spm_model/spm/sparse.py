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

from spm_data.errors import SparseError


BATCH = 64  # l1 problems per linear programme (knn solver)


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


def l1_weights_batch(targets: np.ndarray, dictionaries: np.ndarray) -> np.ndarray:
    """Many independent l1 problems as one block-diagonal linear programme (HiGHS's
    per-call overhead dominates problems this small). targets (B, m), dictionaries
    (B, m, n) -> (B, n); a batch HiGHS cannot solve is redone one problem at a time."""
    from scipy import sparse

    B, m, n = dictionaries.shape
    blocks = [np.vstack([D, np.ones((1, n))]) for D in dictionaries]
    A = sparse.block_diag([np.hstack([a, -a]) for a in blocks], format="csr")
    b = np.concatenate([np.append(t, 1.0) for t in targets])
    res = linprog(np.ones(2 * n * B), A_eq=A, b_eq=b, bounds=(0, None), method="highs")
    if res.status != 0:
        return np.stack([l1_weights(t, D) for t, D in zip(targets, dictionaries)])
    x = res.x.reshape(B, 2 * n)
    return x[:, :n] - x[:, n:]


def sparse_weights(M: np.ndarray, method: str = "exact", k: int = 64) -> np.ndarray:
    """S (t, t): column i holds Eq. 5's weights of sample i (M is (m, t), samples in columns)."""
    m, t = M.shape
    if t < 3:
        raise SparseError(f"need at least 3 samples, got {t}")
    S = np.zeros((t, t))
    if method == "exact":
        for i in range(t):
            others = np.delete(np.arange(t), i)
            S[others, i] = l1_weights(M[:, i], M[:, others])
        return S
    if method != "knn":
        raise SparseError(f"method must be 'exact' or 'knn', got {method!r}")
    k = min(k, t - 1)
    for start in range(0, t, BATCH):
        rows = np.arange(start, min(t, start + BATCH))
        d2 = ((M.T[rows, None, :] - M.T[None, :, :]) ** 2).sum(axis=2)
        d2[np.arange(len(rows)), rows] = np.inf
        others = np.argsort(d2, axis=1, kind="stable")[:, :k]
        weights = l1_weights_batch(M.T[rows], M.T[others].transpose(0, 2, 1))
        S[others, rows[:, None]] = weights
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

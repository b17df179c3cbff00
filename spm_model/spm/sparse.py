"""Sparse re-projection (paper §2.3, Eq. 5), read as Sparsity Preserving Projections
(Qiao, Chen & Tan 2010, the paper's reference for it; see docs/method.md).

Eq. 5: every training vector m_i is written as an affine combination of the
others with the smallest l1 norm: ``min ||r_i||_1 s.t. m_i = M r_i, 1^T r_i = 1,
r_ii = 0``. The weights S = [r_1 ... r_t] define the projection: the directions
w maximising ``w^T M S_b M^T w / w^T M M^T w`` with ``S_b = S + S^T - S^T S``,
a generalised eigenproblem; a query vector is projected with the same W.

Solvers: ``exact`` solves each l1 problem over all other samples; ``knn`` the same
problem over the k nearest neighbours only. Both solve all their problems at once
with ``l1_simplex``, a two-phase primal simplex vectorised across problems (one
shared dictionary with each problem's own column barred, or one dictionary per
problem), and keep an answer only with its optimality certificate (a dual vector:
feasible, and equal in objective to sum |r| to 1e-9); the rest go to ``l1_weights``,
one HiGHS linear programme each (the reference, with its least-squares fallback).
When a sample lies inside the others' convex hull the optimum is not unique (every
convex combination reproducing it has norm 1): both solvers return an optimal
vertex, not necessarily the same one (docs/method.md).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import linprog

from spm_model.errors import SparseError


BATCH = 64  # samples per neighbour search (knn solver)


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


PIVOT_TOL = 1e-9    # smallest |pivot| the ratio test accepts
COST_TOL = 1e-9     # a reduced cost above -COST_TOL is not an improvement
REFACTOR = 32       # simplex steps between fresh basis inverses
CERT_TOL = 1e-9     # relative tolerance of the optimality certificate


def _columns(A: np.ndarray, signs: np.ndarray, rows: np.ndarray, var: np.ndarray) -> np.ndarray:
    """Columns of the split programme's matrix [A, -A, diag(signs)] for variables var (P, q)
    of problems rows (P,) -> (P, q, m). A is (m, n) shared or (P_all, m, n) per problem."""
    n = A.shape[-1]
    j = var % n
    cols = A.T[j] if A.ndim == 2 else A[rows[:, None], :, j]
    cols = cols * np.where((var >= n) & (var < 2 * n), -1.0, 1.0)[..., None]
    art = var >= 2 * n
    if art.any():
        p, q = np.nonzero(art)
        k = var[p, q] - 2 * n
        cols[p, q] = 0.0
        cols[p, q, k] = signs[rows[p], k]
    return cols


def _inverses(A, signs, basis, rows) -> np.ndarray:
    """Basis inverses (P, m, m) of problems rows; NaN for a singular basis."""
    Bm = _columns(A, signs, rows, basis[rows]).transpose(0, 2, 1)
    try:
        return np.linalg.inv(Bm)
    except np.linalg.LinAlgError:
        out = np.full(Bm.shape, np.nan)
        for p, B in enumerate(Bm):
            try:
                out[p] = np.linalg.inv(B)
            except np.linalg.LinAlgError:
                pass
        return out


def _pivots(A, b, signs, exclude, basis, phase, rows, max_iter):
    """Primal simplex steps (Dantzig's rule, Bland's after 20 m steps) for problems rows
    until each is optimal in this phase (cost: artificials in phase 1, |r| in phase 2);
    the basis inverses are updated per pivot and recomputed every REFACTOR steps.
    Returns the rows that did not finish within max_iter or met an unbounded ray."""
    m, n = b.shape[1], A.shape[-1]
    failed = []
    Binv = None
    for step in range(max_iter):
        if len(rows) == 0:
            break
        if step % REFACTOR == 0:
            Binv = _inverses(A, signs, basis, rows)
            bad = ~np.isfinite(Binv).all(axis=(1, 2))
            failed.extend(rows[bad].tolist())
            rows, Binv = rows[~bad], Binv[~bad]
        xB = np.maximum(np.einsum("pij,pj->pi", Binv, b[rows]), 0.0)
        art = basis[rows] >= 2 * n
        y = np.einsum("pk,pkm->pm", art if phase == 1 else ~art, Binv)
        yA = y @ A if A.ndim == 2 else np.einsum("pm,pmn->pn", y, A[rows])
        if exclude is not None:
            yA[np.arange(len(rows)), exclude[rows]] = 0.0
        # Reduced costs: base - yA_j for u_j, base + yA_j for v_j; the better of the pair.
        gain = np.abs(yA) - (0.0 if phase == 1 else 1.0)
        j = np.argmax(gain, axis=1) if step < 20 * m else np.argmax(gain > COST_TOL, axis=1)
        pick = np.arange(len(rows)), j
        keep = gain[pick] > COST_TOL
        enter = np.where(yA[pick] > 0, j, j + n)
        rows, enter, Binv, xB, art = rows[keep], enter[keep], Binv[keep], xB[keep], art[keep]
        if len(rows) == 0:
            break
        d = np.einsum("pij,pj->pi", Binv, _columns(A, signs, rows, enter[:, None])[:, 0])
        with np.errstate(divide="ignore", invalid="ignore"):
            theta = np.where(d > PIVOT_TOL, xB / d, np.inf)
        if phase == 2:  # an artificial left at zero must not move: it leaves at once
            theta = np.where(art & (np.abs(d) > PIVOT_TOL), 0.0, theta)
        leave = np.argmin(theta, axis=1)
        keep = np.isfinite(theta[np.arange(len(rows)), leave])
        failed.extend(rows[~keep].tolist())
        rows, enter, leave, Binv, d = rows[keep], enter[keep], leave[keep], Binv[keep], d[keep]
        basis[rows, leave] = enter
        Binv = _pivot_inverse(Binv, d, leave)
    else:
        failed.extend(rows.tolist())
    return np.asarray(failed, dtype=int)


def _pivot_inverse(Binv: np.ndarray, d: np.ndarray, leave: np.ndarray) -> np.ndarray:
    """The basis inverses after column leave of each basis is replaced by the column whose
    representation in the old basis is d (the product-form update)."""
    idx = np.arange(len(leave))
    row = Binv[idx, leave] / d[idx, leave][:, None]
    Binv = Binv - d[:, :, None] * row[:, None, :]
    Binv[idx, leave] = row
    return Binv


def l1_simplex(A: np.ndarray, b: np.ndarray, exclude: np.ndarray | None = None,
               max_iter: int = 2000) -> tuple[np.ndarray, np.ndarray]:
    """min ||r||_1 s.t. A r = b for P problems at once, by a vectorised two-phase primal
    simplex on r = u - v (u, v >= 0). A (m, n) shared or (P, m, n) per problem; b (P, m);
    exclude (P,) a column problem p may not use, or None. -> r (P, n) and ok (P,) bool:
    ok where r is an optimal vertex (feasible, every reduced cost >= -1e-9); the others
    (infeasible, or not finished in max_iter steps) are zero and left to the caller."""
    A = np.asarray(A, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    P, m = b.shape
    n = A.shape[-1]
    signs = np.where(b < 0, -1.0, 1.0)
    basis = np.tile(np.arange(2 * n, 2 * n + m), (P, 1))
    rows = np.arange(P)
    ok = np.ones(P, dtype=bool)
    ok[_pivots(A, b, signs, exclude, basis, 1, rows, max_iter)] = False
    r = _solution(A, b, signs, basis, np.arange(P))
    ok &= _feasible(A, b, r)                          # phase 1 reached a feasible point
    ok[_pivots(A, b, signs, exclude, basis, 2, np.flatnonzero(ok), max_iter)] = False
    r = _solution(A, b, signs, basis, np.arange(P))
    ok &= _feasible(A, b, r) & _optimal(A, b, signs, exclude, basis, r)
    r[~ok] = 0.0
    return r, ok


def _optimal(A, b, signs, exclude, basis, r) -> np.ndarray:
    """(P,) bool: the duality certificate of each basis. y solves B^T y = c_B (c = 1 on
    the weights, 0 on artificials); y is dual feasible when |a_j . y| <= 1 + CERT_TOL for
    every usable column j, and then sum |r| - b . y <= CERT_TOL (1 + sum |r|) proves r
    optimal to that relative tolerance (weak duality: every feasible r' has
    sum |r'| >= b . y / (1 + CERT_TOL))."""
    n, rows = A.shape[-1], np.arange(len(b))
    Bm = _columns(A, signs, rows, basis).transpose(0, 2, 1)
    ok = np.isfinite(r).all(axis=1)
    y = np.zeros(b.shape)
    try:
        y[ok] = np.linalg.solve(Bm[ok].transpose(0, 2, 1), (basis[ok] < 2 * n).astype(float)[..., None])[..., 0]
    except np.linalg.LinAlgError:
        return np.zeros(len(b), bool)
    yA = np.abs(y @ A if A.ndim == 2 else np.einsum("pm,pmn->pn", y, A))
    if exclude is not None:
        yA[rows, exclude] = 0.0
    norm = np.abs(np.nan_to_num(r)).sum(axis=1)
    gap = norm - np.einsum("pm,pm->p", b, y)
    return ok & (yA.max(axis=1) <= 1 + CERT_TOL) & (np.abs(gap) <= CERT_TOL * (1 + norm))


def _feasible(A, b, r) -> np.ndarray:
    """(P,) bool: A r = b to 1e-9 relative."""
    Ar = np.einsum("mn,pn->pm", A, r) if A.ndim == 2 else np.einsum("pmn,pn->pm", A, r)
    return np.abs(Ar - b).max(axis=1) <= 1e-9 * (1.0 + np.abs(b).max(axis=1))


def _solution(A, b, signs, basis, rows) -> np.ndarray:
    """r (P, n) of the current bases; NaN rows where a basis is singular."""
    n = A.shape[-1]
    Bm = _columns(A, signs, rows, basis[rows]).transpose(0, 2, 1)
    xB = np.full(b[rows].shape, np.nan)
    try:
        xB = np.linalg.solve(Bm, b[rows][..., None])[..., 0]
    except np.linalg.LinAlgError:
        for p in range(len(rows)):
            try:
                xB[p] = np.linalg.solve(Bm[p], b[rows[p]])
            except np.linalg.LinAlgError:
                pass
    r = np.zeros((len(rows), n))
    p, k = np.nonzero(basis[rows] < 2 * n)
    var = basis[rows][p, k]
    np.add.at(r, (p, var % n), np.where(var < n, 1.0, -1.0) * xB[p, k])
    r[~np.isfinite(xB).all(axis=1)] = np.nan
    return r


def sparse_weights(M: np.ndarray, method: str = "exact", k: int = 64) -> np.ndarray:
    """S (t, t): column i holds Eq. 5's weights of sample i (M is (m, t), samples in columns)."""
    m, t = M.shape
    if t < 3:
        raise SparseError(f"need at least 3 samples, got {t}")
    S = np.zeros((t, t))
    A = np.vstack([M, np.ones((1, t))])
    if method == "exact":
        b = A.T
        r, ok = l1_simplex(A, b, exclude=np.arange(t))
        S[:] = r.T
        for i in np.flatnonzero(~ok):  # the reference solve (and its fallback) for the rest
            others = np.delete(np.arange(t), i)
            S[:, i] = 0.0
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
        weights, ok = l1_simplex(A[:, others].transpose(1, 0, 2), A.T[rows])
        for j in np.flatnonzero(~ok):
            weights[j] = l1_weights(M[:, rows[j]], M[:, others[j]])
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

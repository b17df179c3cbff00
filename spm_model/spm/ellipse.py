"""Ellipse fits over cluster centres (paper §2.2, Eq. 1) and the ellipse's geometry.

Eq. 1 as printed, ``mean_k psi(x_k)^2 + lambda * sum_{n<=5} Delta_n^2``, is
minimised by ``Delta = 0``. We exclude it, and force an ellipse, with the
normalisation ``4AC - B^2 = 1``, in coordinates centred on the points' mean
and scaled to unit RMS radius (so lambda = 0.1 means the same for every image).
Two solvers: particle swarm optimisation, as the paper uses (each particle is
rescaled onto the constraint; non-ellipses cost infinity), and the closed-form
direct least-squares fit of Fitzgibbon et al. (1999), Halir & Flusser's stable
form, which has the same constraint without the regulariser.

Speed: a fit has 8 points, so its cost is numpy's per-call overhead, not
arithmetic. The swarm therefore works in place on preallocated (6, particles)
buffers, draws its random numbers in blocks of iterations, and the 3 x 3 and
2 x 2 solves call LAPACK directly (the same routines numpy.linalg calls), in the
same order of floating-point operations as the plain formulation
(tests/model/spm/test_ellipse.py checks the two agree).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
from scipy.linalg import lapack

from spm_model.errors import EllipseError


LAMBDA = 0.1
UNIT_CIRCLE = np.array([0.5, 0.0, 0.5, 0.0, 0.0, -0.5])  # x^2 + y^2 = 1, on the constraint
_NOT_F = np.diag([1.0, 1, 1, 1, 1, 0])  # Eq. 1 regularises A..E, not the bias F
_C1_INVERSE = np.array([[0.5], [-1.0], [0.5]])  # C1^-1 M = M[::-1] * this, C1 = [[0,0,2],[0,-1,0],[2,0,0]]
_BLOCK = 20  # iterations whose random numbers are drawn at once


@dataclass(frozen=True)
class Ellipse:
    """centre (2,), semi-axes a >= b, major-axis unit direction u (2,) with u_x > 0
    (or u_x = 0 and u_y > 0), in the points' own units (pixels)."""

    centre: np.ndarray
    a: float
    b: float
    u: np.ndarray

    @property
    def eccentricity(self) -> float:
        return math.sqrt(max(0.0, 1.0 - (self.b / self.a) ** 2))

    @property
    def foci(self) -> np.ndarray:
        """(2, 2): the focus behind the major-axis direction u first, then the one ahead."""
        c = math.sqrt(max(0.0, self.a ** 2 - self.b ** 2))
        return np.stack([self.centre - c * self.u, self.centre + c * self.u])


def _normalise(points: np.ndarray):
    points = np.asarray(points, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 2:
        raise EllipseError(f"expected (N, 2) points, got shape {points.shape}")
    if len(points) < 5:
        raise EllipseError(f"an ellipse needs at least 5 points, got {len(points)}")
    n = len(points)
    mean = np.add.reduce(points, 0) / n  # points.mean(axis=0), without its wrapper
    d = points - mean
    scale = math.sqrt(np.add.reduce(np.add.reduce(d * d, 1)) / n)
    if not math.isfinite(scale) or scale <= 1e-12:
        raise EllipseError("points coincide")
    p = d / scale
    # Collinear points have no ellipse; LAPACK may still return a conic with axes of 1e13 px
    # there (seen with some BLAS builds), so the spread across the line is checked first.
    sxx, syy, sxy = np.add.reduce(p * p, 0).tolist() + [float(np.dot(p[:, 0], p[:, 1]))]
    if (sxx * syy - sxy * sxy) / (n * n) < 1e-12:
        raise EllipseError("points are degenerate (collinear)")
    return p, mean, scale


def _design(p: np.ndarray) -> np.ndarray:
    x, y = p[:, 0], p[:, 1]
    return np.column_stack([x * x, x * y, y * y, x, y, np.ones_like(x)])


def conic_cost(conics: np.ndarray, design: np.ndarray, lam: float = LAMBDA) -> np.ndarray:
    """Eq. 1 for (P, 6) conics already on the constraint: mean squared algebraic
    residual plus lam * the squares of A..E (F is the bias, unregularised)."""
    residual = design @ conics.T  # (N, P)
    return (residual ** 2).mean(axis=0) + lam * (conics[:, :5] ** 2).sum(axis=1)


def _solve(a: np.ndarray, b: np.ndarray, message: str) -> np.ndarray:
    """numpy.linalg.solve for a tiny system (LAPACK dgesv, without numpy's per-call overhead)."""
    x, info = lapack.dgesv(a, b)[2:]
    if info != 0:
        raise EllipseError(message)
    return np.ascontiguousarray(x)  # LAPACK's column-major order would change later products' rounding


def _real_eigenvectors(m: np.ndarray) -> np.ndarray:
    """np.real(np.linalg.eig(m)[1]) for a real square matrix (LAPACK dgeev): a complex
    pair's two vectors share the real part, LAPACK's column of the first."""
    wi, _, vectors, info = lapack.dgeev(m, compute_vl=0)[1:]
    if info != 0:
        raise EllipseError("no ellipse fits these points (eigenvalues did not converge)")
    for j, imaginary in enumerate(wi.tolist()):
        if imaginary > 0:
            vectors[:, j + 1] = vectors[:, j]
    return vectors


def direct_conic(p: np.ndarray, gram: np.ndarray | None = None) -> np.ndarray:
    """Halir & Flusser's direct ellipse fit in normalised coordinates: (6,) with 4AC - B^2 = 1.
    ``gram``: the design matrix's D^T D (6, 6), when the caller has it."""
    S = _gram(p) if gram is None else gram
    S1, S2, S3 = S[:3, :3], S[:3, 3:], S[3:, 3:]
    T = -_solve(S3, S2.T, "points are degenerate (collinear?)")
    M = S1 + S2 @ T
    vectors = _real_eigenvectors(M[::-1] * _C1_INVERSE)
    good = [j for j, (a, b, c) in enumerate(zip(*vectors.tolist())) if 4 * a * c - b * b > 0]
    if not good:
        raise EllipseError("no ellipse fits these points")
    a1 = vectors[:, good[0]]
    conic = np.concatenate([a1, T @ a1])
    c0, c1, c2 = conic[:3].tolist()
    disc = 4 * c0 * c2 - c1 * c1
    return conic / math.sqrt(disc) if disc > 1e-12 else conic


def _gram(p: np.ndarray) -> np.ndarray:
    design = _design(p)
    return design.T @ design


@functools.lru_cache(maxsize=8)
def _constants(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Read-only (2, n) rows of 4 and 1, and (n,) 1e-12: array operands are cheaper than scalars."""
    four, tiny = np.repeat([[4.0], [1.0]], n, axis=1), np.full(n, 1e-12)
    four.flags.writeable = tiny.flags.writeable = False
    return four, tiny


class _Swarm:
    """A particle swarm over conics, updated in place: coefficients in rows, particles in
    columns. Each step does the plain formulation's floating-point operations in the same
    order (tests/model/spm/test_ellipse.py compares the two bit for bit); the buffers and
    their views are made once, as numpy's per-call overhead is the cost at this size."""

    def __init__(self, start: np.ndarray, G: np.ndarray):
        n = self.n = len(start)
        self.state = np.empty((7, n))  # rows 0-5: positions, row 6: their cost
        x, cost = self.x, self.cost = self.state[:6], self.state[6]
        x[...] = start.T
        # Eq. 1 as x^T G x: the terms (x_i G_ij) x_j summed over (i, j) in order, as np.einsum does.
        rows, cols = x.strides
        self.quadratic = (np.ndarray((6, 6, n), x.dtype, x, 0, (rows, 0, cols)),  # x_i, repeated over j
                          np.repeat(G[:, :, None], n, axis=2), np.empty((6, 6, n)),
                          np.ndarray((6, 6, n), x.dtype, x, 0, (0, rows, cols)), cost)  # x_j, repeated over i
        # 4AC - B^2 from rows (A, B) * (4, 1) * (C, B); columns below 1e-12 are no ellipse.
        products = np.empty((2, n))
        self.ok, self.root = np.empty(n, dtype=bool), np.empty(n)
        four, tiny = _constants(n)
        self.constraint = (x, x[0:2], four, products, x[2:0:-1], products[0], products[1], np.empty(n), tiny,
                           self.ok, self.root)
        # pulls[0]: each particle's best position (row 6: its cost); pulls[1, :6]: the swarm's best.
        self.pulls = np.empty((2, 7, n))
        self.moves = np.empty((3, 6, n))  # velocity, pull to own best, pull to the swarm's best
        self.scales = np.empty((_BLOCK, 3, 6, n))  # per iteration: 0.72, 1.49 r1, 1.49 r2
        self.scales[:, 0] = 0.72
        self.motion = (self.pulls[:, :6], x, self.moves[1:], self.moves, *self.moves)
        better = np.empty(n, dtype=bool)
        self.keep = (cost, self.pulls[0, 6], better, self.ok, self.pulls[0],
                     np.ndarray((7, n), better.dtype, better, 0, (0, better.strides[0])), self.state)

    def constrain(self) -> None:
        """Scale each column onto 4AC - B^2 = 1 (a column that is no ellipse stays as it is)."""
        x, ab, four, products, cb, fourac, bb, disc, tiny, ok, root = self.constraint
        np.multiply(ab, four, products)
        np.multiply(products, cb, products)
        np.subtract(fourac, bb, disc)
        np.greater(disc, tiny, ok)
        root.fill(1.0)
        np.sqrt(disc, out=root, where=ok)
        np.divide(x, root, x)

    def score(self) -> None:
        """Constrain, then Eq. 1 per column into ``cost`` (valid where ``ok``)."""
        self.constrain()
        xi, G, terms, xj, cost = self.quadratic
        np.multiply(xi, G, terms)
        np.einsum("ijp,ijp->p", terms, xj, out=cost)

    def start(self, velocity: np.ndarray) -> tuple[int, float]:
        """Score the start; returns the best particle and its cost."""
        self.score()
        self.moves[0] = velocity.T
        self.pulls[0] = self.state
        self.pulls[0, 6, ~self.ok] = np.inf
        return self.best()

    def draw(self, rng, count: int) -> None:
        """r1, r2 of the next ``count`` iterations, drawn as the plain loop draws them one by one."""
        r = rng.random((count, 2, self.n, 6))
        np.multiply(r.transpose(0, 1, 3, 2), 1.49, out=self.scales[:count, 1:])

    def run(self, rng, best_cost: float, iterations: int, patience: int, tol: float) -> float:
        """The iterations: velocity = 0.72 velocity + 1.49 r1 (own best - x) + 1.49 r2 (best - x);
        x += velocity; score; keep each particle's improvement and the swarm's, until ``patience``
        iterations improved the best cost by less than ``tol`` (relative). Returns the best cost."""
        pulls, x, pull, moves, velocity, own, best = self.motion
        cost, own_cost, better, ok, own_best, better_rows, state = self.keep
        xi, G, terms, xj, _ = self.quadratic
        scales, stale = list(self.scales), 0
        for it in range(iterations):
            if it % _BLOCK == 0:
                self.draw(rng, min(_BLOCK, iterations - it))
            np.subtract(pulls, x, pull)
            np.multiply(moves, scales[it % _BLOCK], moves)
            np.add(velocity, own, velocity)
            np.add(velocity, best, velocity)
            np.add(x, velocity, x)
            self.constrain()
            np.multiply(xi, G, terms)
            np.einsum("ijp,ijp->p", terms, xj, out=cost)
            np.less(cost, own_cost, better)
            np.logical_and(better, ok, better)
            np.putmask(own_best, better_rows, state)  # np.copyto(..., where=better), at half the cost
            g = int(own_cost.argmin())
            low = own_cost.item(g)
            improved = best_cost - low > tol * abs(best_cost) if math.isfinite(best_cost) else True
            if low < best_cost:
                best_cost = low
                self.take_best(g)
            stale = 0 if improved else stale + 1
            if stale >= patience:
                break
        return best_cost

    def best(self) -> tuple[int, float]:
        own_cost = self.keep[1]
        g = int(own_cost.argmin())
        return g, own_cost.item(g)

    def take_best(self, g: int) -> None:
        self.pulls[1, :6] = self.pulls[0, :6, g, None]


def _swarm_start(rng, gram: np.ndarray, p: np.ndarray, particles: int) -> np.ndarray:
    """(n, 6) particles around the direct fit (if any) and the unit circle, anchors first."""
    try:
        anchors = [direct_conic(p, gram), UNIT_CIRCLE]
    except EllipseError:
        anchors = [UNIT_CIRCLE]
    per = particles // len(anchors)
    start = rng.normal(0, 0.3, (per * len(anchors), 6))  # one draw: the same numbers as one per anchor
    for i, a in enumerate(anchors):
        start[i * per:(i + 1) * per] += a
    start[: len(anchors)] = anchors
    return start


def pso_conic(p: np.ndarray, lam: float = LAMBDA, particles: int = 48, iterations: int = 120,
              seed: int = 0, patience: int = 20, tol: float = 1e-10) -> np.ndarray:
    """Minimise Eq. 1 on 4AC - B^2 = 1 with a particle swarm (inertia 0.72, pulls 1.49).

    Particles start around the unregularised direct fit and the unit circle, so
    the swarm begins from valid ellipses; the result is the best seen. The swarm
    stops early once the best cost has improved by less than ``tol`` (relative)
    for ``patience`` iterations."""
    rng = np.random.default_rng(seed)
    gram = _gram(p)
    swarm = _Swarm(_swarm_start(rng, gram, p, particles), gram / len(p) + lam * _NOT_F)
    swarm.constrain()
    g, best_cost = swarm.start(rng.normal(0, 0.1, (swarm.n, 6)))
    swarm.take_best(g)
    best_cost = swarm.run(rng, best_cost, iterations, patience, tol)
    if not math.isfinite(best_cost):
        raise EllipseError("the swarm found no ellipse")
    return swarm.pulls[1, :6, 0].copy()


def conic_to_ellipse(conic: np.ndarray) -> Ellipse:
    """Geometry of an ellipse conic (6,) in the coordinates it was fitted in."""
    conic = np.asarray(conic, dtype=np.float64)
    if conic[0] + conic[2] < 0:  # -conic is the same curve; make the quadratic part positive
        conic = -conic
    A, B, C, D, E, F = conic.tolist()
    centre = _solve(np.array([[2 * A, B], [B, 2 * C]]), np.array([-D, -E]), "degenerate conic (no centre)")
    cx, cy = centre.tolist()
    F0 = F + (D * cx + E * cy) / 2.0
    values, vectors, info = lapack.dsyevd(np.array([[A, B / 2], [B / 2, C]]), lower=1)  # numpy.linalg.eigh
    if info != 0 or values[0] <= 0 or F0 >= 0:
        raise EllipseError("the fitted conic is not a real ellipse")
    a, b = math.sqrt(-F0 / values[0]), math.sqrt(-F0 / values[1])  # the smaller eigenvalue: the major axis
    u = vectors[:, 0]
    if u[0] < 0 or (abs(u[0]) < 1e-12 and u[1] < 0):
        u = -u
    return Ellipse(centre=centre, a=a, b=b, u=u)


def fit_ellipse(points, method: str = "pso", lam: float = LAMBDA, seed: int = 0) -> Ellipse:
    """Fit an ellipse to (N >= 5, 2) points (pixels); ``method`` "pso" (Eq. 1, the
    paper's) or "direct" (closed form). Returns it in pixel coordinates."""
    p, mean, scale = _normalise(points)
    if method == "pso":
        conic = pso_conic(p, lam=lam, seed=seed)
    elif method == "direct":
        conic = direct_conic(p)
    else:
        raise EllipseError(f"method must be 'pso' or 'direct', got {method!r}")
    e = conic_to_ellipse(conic)
    return Ellipse(centre=e.centre * scale + mean, a=e.a * scale, b=e.b * scale, u=e.u)

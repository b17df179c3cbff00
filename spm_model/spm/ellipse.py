"""Ellipse fits over cluster centres (paper §2.2, Eq. 1) and the ellipse's geometry.

Eq. 1 as printed, ``mean_k psi(x_k)^2 + lambda * sum_{n<=5} Delta_n^2``, is
minimised by ``Delta = 0``. We exclude it, and force an ellipse, with the
normalisation ``4AC - B^2 = 1``, in coordinates centred on the points' mean
and scaled to unit RMS radius (so lambda = 0.1 means the same for every image).
Two solvers: particle swarm optimisation, as the paper uses (each particle is
rescaled onto the constraint; non-ellipses cost infinity), and the closed-form
direct least-squares fit of Fitzgibbon et al. (1999), Halir & Flusser's stable
form, which has the same constraint without the regulariser.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from spm_data.errors import EllipseError


LAMBDA = 0.1


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
        return float(np.sqrt(max(0.0, 1.0 - (self.b / self.a) ** 2)))

    @property
    def foci(self) -> np.ndarray:
        """(2, 2): the focus behind the major-axis direction u first, then the one ahead."""
        c = np.sqrt(max(0.0, self.a ** 2 - self.b ** 2))
        return np.stack([self.centre - c * self.u, self.centre + c * self.u])


def _normalise(points: np.ndarray):
    points = np.asarray(points, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 2:
        raise EllipseError(f"expected (N, 2) points, got shape {points.shape}")
    if len(points) < 5:
        raise EllipseError(f"an ellipse needs at least 5 points, got {len(points)}")
    mean = points.mean(axis=0)
    scale = np.sqrt(((points - mean) ** 2).sum(axis=1).mean())
    if not np.isfinite(scale) or scale <= 1e-12:
        raise EllipseError("points coincide")
    return (points - mean) / scale, mean, scale


def _design(p: np.ndarray) -> np.ndarray:
    x, y = p[:, 0], p[:, 1]
    return np.column_stack([x * x, x * y, y * y, x, y, np.ones_like(x)])


def conic_cost(conics: np.ndarray, design: np.ndarray, lam: float = LAMBDA) -> np.ndarray:
    """Eq. 1 for (P, 6) conics already on the constraint: mean squared algebraic
    residual plus lam * the squares of A..E (F is the bias, unregularised)."""
    residual = design @ conics.T  # (N, P)
    return (residual ** 2).mean(axis=0) + lam * (conics[:, :5] ** 2).sum(axis=1)


def _onto_constraint(conics: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Scale each conic so that 4AC - B^2 = 1; returns (conics, is_ellipse)."""
    disc = 4 * conics[:, 0] * conics[:, 2] - conics[:, 1] ** 2
    ok = disc > 1e-12
    scaled = conics / np.sqrt(np.where(ok, disc, 1.0))[:, None]
    return scaled, ok


def direct_conic(p: np.ndarray) -> np.ndarray:
    """Halir & Flusser's direct ellipse fit in normalised coordinates: (6,) with 4AC - B^2 = 1."""
    D1 = _design(p)[:, :3]
    D2 = _design(p)[:, 3:]
    S1, S2, S3 = D1.T @ D1, D1.T @ D2, D2.T @ D2
    try:
        T = -np.linalg.solve(S3, S2.T)
    except np.linalg.LinAlgError:
        raise EllipseError("points are degenerate (collinear?)") from None
    M = S1 + S2 @ T
    M = np.array([M[2] / 2, -M[1], M[0] / 2])  # C1^-1 M with C1 = [[0,0,2],[0,-1,0],[2,0,0]]
    values, vectors = np.linalg.eig(M)
    vectors = np.real(vectors)
    cond = 4 * vectors[0] * vectors[2] - vectors[1] ** 2
    good = np.flatnonzero(cond > 0)
    if len(good) == 0:
        raise EllipseError("no ellipse fits these points")
    a1 = vectors[:, good[0]]
    conic = np.concatenate([a1, T @ a1])
    return _onto_constraint(conic[None])[0][0]


def pso_conic(p: np.ndarray, lam: float = LAMBDA, particles: int = 48, iterations: int = 120,
              seed: int = 0, patience: int = 20, tol: float = 1e-10) -> np.ndarray:
    """Minimise Eq. 1 on 4AC - B^2 = 1 with a particle swarm (inertia 0.72, pulls 1.49).

    Particles start around the unregularised direct fit and the unit circle, so
    the swarm begins from valid ellipses; the result is the best seen. The swarm
    stops early once the best cost has improved by less than ``tol`` (relative)
    for ``patience`` iterations."""
    rng = np.random.default_rng(seed)
    design = _design(p)
    try:
        anchors = [direct_conic(p)]
    except EllipseError:
        anchors = []
    anchors.append(np.array([0.5, 0.0, 0.5, 0.0, 0.0, -0.5]))  # x^2 + y^2 = 1, on the constraint
    start = np.concatenate([a + rng.normal(0, 0.3, (particles // len(anchors), 6)) for a in anchors])
    start[: len(anchors)] = anchors
    position, ok = _onto_constraint(start)
    velocity = rng.normal(0, 0.1, position.shape)

    # Eq. 1 is the quadratic form x^T G x: a 6 x 6 matrix, whatever the number of points.
    G = design.T @ design / len(design) + lam * np.diag([1.0, 1, 1, 1, 1, 0])

    def score(x):
        x, valid = _onto_constraint(x)
        return x, np.where(valid, np.einsum("pi,ij,pj->p", x, G, x), np.inf)

    position, cost = score(position)
    best_own, best_own_cost = position.copy(), cost.copy()
    g = int(np.argmin(cost))
    best, best_cost = position[g].copy(), cost[g]
    stale = 0
    for _ in range(iterations):
        r1, r2 = rng.random(position.shape), rng.random(position.shape)
        velocity = 0.72 * velocity + 1.49 * r1 * (best_own - position) + 1.49 * r2 * (best - position)
        position, cost = score(position + velocity)
        better = cost < best_own_cost
        best_own[better], best_own_cost[better] = position[better], cost[better]
        g = int(np.argmin(best_own_cost))
        improved = best_cost - best_own_cost[g] > tol * abs(best_cost) if np.isfinite(best_cost) else True
        if best_own_cost[g] < best_cost:
            best, best_cost = best_own[g].copy(), best_own_cost[g]
        stale = 0 if improved else stale + 1
        if stale >= patience:
            break
    if not np.isfinite(best_cost):
        raise EllipseError("the swarm found no ellipse")
    return best


def conic_to_ellipse(conic: np.ndarray) -> Ellipse:
    """Geometry of an ellipse conic (6,) in the coordinates it was fitted in."""
    conic = np.asarray(conic, dtype=np.float64)
    if conic[0] + conic[2] < 0:  # -conic is the same curve; make the quadratic part positive
        conic = -conic
    A, B, C, D, E, F = conic
    Q = np.array([[2 * A, B], [B, 2 * C]])
    try:
        centre = np.linalg.solve(Q, [-D, -E])
    except np.linalg.LinAlgError:
        raise EllipseError("degenerate conic (no centre)") from None
    F0 = F + (D * centre[0] + E * centre[1]) / 2.0
    values, vectors = np.linalg.eigh(np.array([[A, B / 2], [B / 2, C]]))
    if values[0] <= 0 or F0 >= 0:
        raise EllipseError("the fitted conic is not a real ellipse")
    a, b = np.sqrt(-F0 / values[0]), np.sqrt(-F0 / values[1])  # the smaller eigenvalue: the major axis
    u = vectors[:, 0]
    if u[0] < 0 or (abs(u[0]) < 1e-12 and u[1] < 0):
        u = -u
    return Ellipse(centre=centre, a=float(a), b=float(b), u=u)


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

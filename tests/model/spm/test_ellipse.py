"""spm_model.spm.ellipse: the direct and PSO conic fits against known ellipses and Eq. 1's constrained
minimum; degenerate inputs refused."""

import numpy as np
import pytest
from scipy.optimize import minimize

from spm_model.spm.ellipse import EllipseError, _design, _normalise, conic_cost, direct_conic, fit_ellipse, pso_conic
from tests.helpers import ellipse_points


def radial_error(points, e):
    """|sqrt((x'/a)^2 + (y'/b)^2) - 1| for points in the ellipse's own frame."""
    d = points - e.centre
    v = np.array([-e.u[1], e.u[0]])
    return np.abs(np.sqrt((d @ e.u / e.a) ** 2 + (d @ v / e.b) ** 2) - 1)


def test_direct_fit_through_known_points_gives_known_foci():
    pts, true = ellipse_points()
    e = fit_ellipse(pts, "direct")
    np.testing.assert_allclose(e.foci, true.foci, atol=1e-7)
    c = np.sqrt(30.0 ** 2 - 18.0 ** 2)
    np.testing.assert_allclose(np.linalg.norm(e.foci - e.centre, axis=1), [c, c], atol=1e-7)
    assert e.eccentricity == pytest.approx(c / 30.0)
    assert radial_error(pts, e).max() < 1e-9


def test_pso_reaches_the_constrained_minimum_of_eq1():
    pts, _ = ellipse_points(n=8)
    for seed, noise in [(0, 0.0), (1, 1.5), (2, 3.0)]:
        p = pts + np.random.default_rng(seed).normal(0, noise, pts.shape)
        pn, _, _ = _normalise(p)
        design = _design(pn)
        cost = lambda x, design=design: conic_cost(np.asarray(x)[None], design)[0]  # noqa: E731
        constraint = {"type": "eq", "fun": lambda x: 4 * x[0] * x[2] - x[1] ** 2 - 1}
        reference = min(minimize(cost, x0, constraints=[constraint], method="SLSQP").fun
                        for x0 in (direct_conic(pn), np.array([0.5, 0, 0.5, 0, 0, -0.5])))
        assert cost(pso_conic(pn, seed=seed)) <= reference * (1 + 1e-5)


def test_both_fits_stay_close_to_the_points():
    pts, _ = ellipse_points()
    p = pts + np.random.default_rng(4).normal(0, 1.0, pts.shape)
    assert radial_error(p, fit_ellipse(p, "direct")).mean() < 0.05
    # Eq. 1's regulariser (lambda = 0.1) rounds the ellipse a little: still close.
    assert radial_error(p, fit_ellipse(p, "pso")).mean() < 0.15


def test_degenerate_inputs():
    with pytest.raises(EllipseError, match="at least 5 points"):
        fit_ellipse(np.zeros((4, 2)))
    with pytest.raises(EllipseError):
        fit_ellipse(np.column_stack([np.arange(8.0), 2 * np.arange(8.0)]), "direct")
    with pytest.raises(EllipseError, match="coincide"):
        fit_ellipse(np.ones((8, 2)))


# --------------------------------------------------------------------------- the plain formulation, as a reference

def _plain_onto_constraint(conics):
    disc = 4 * conics[:, 0] * conics[:, 2] - conics[:, 1] ** 2
    ok = disc > 1e-12
    return conics / np.sqrt(np.where(ok, disc, 1.0))[:, None], ok


def _plain_direct(p):
    D1, D2 = _design(p)[:, :3], _design(p)[:, 3:]
    S1, S2, S3 = D1.T @ D1, D1.T @ D2, D2.T @ D2
    T = -np.linalg.solve(S3, S2.T)
    M = S1 + S2 @ T
    vectors = np.real(np.linalg.eig(np.array([M[2] / 2, -M[1], M[0] / 2]))[1])
    a1 = vectors[:, np.flatnonzero(4 * vectors[0] * vectors[2] - vectors[1] ** 2 > 0)[0]]
    return _plain_onto_constraint(np.concatenate([a1, T @ a1])[None])[0][0]


def _plain_pso(p, lam=0.1, particles=48, iterations=120, seed=0, patience=20, tol=1e-10):
    """The swarm written plainly: fresh arrays, fancy indexing, np.einsum, one draw per use."""
    rng = np.random.default_rng(seed)
    design = _design(p)
    anchors = [_plain_direct(p), np.array([0.5, 0.0, 0.5, 0.0, 0.0, -0.5])]
    start = np.concatenate([a + rng.normal(0, 0.3, (particles // 2, 6)) for a in anchors])
    start[:2] = anchors
    position, ok = _plain_onto_constraint(start)
    velocity = rng.normal(0, 0.1, position.shape)
    G = design.T @ design / len(design) + lam * np.diag([1.0, 1, 1, 1, 1, 0])

    def score(x):
        x, valid = _plain_onto_constraint(x)
        return x, np.where(valid, np.einsum("pi,ij,pj->p", x, G, x), np.inf)

    position, cost = score(position)
    own, own_cost = position.copy(), cost.copy()
    best, best_cost, stale = position[np.argmin(cost)].copy(), cost.min(), 0
    for _ in range(iterations):
        r1, r2 = rng.random(position.shape), rng.random(position.shape)
        velocity = 0.72 * velocity + 1.49 * r1 * (own - position) + 1.49 * r2 * (best - position)
        position, cost = score(position + velocity)
        better = cost < own_cost
        own[better], own_cost[better] = position[better], cost[better]
        g = int(np.argmin(own_cost))
        improved = best_cost - own_cost[g] > tol * abs(best_cost)
        if own_cost[g] < best_cost:
            best, best_cost = own[g].copy(), own_cost[g]
        stale = 0 if improved else stale + 1
        if stale >= patience:
            break
    return best


def _plain_geometry(conic):
    """(centre, a, b, u) of a conic with np.linalg.solve and np.linalg.eigh."""
    conic = -conic if conic[0] + conic[2] < 0 else conic
    A, B, C, D, E, F = conic
    centre = np.linalg.solve(np.array([[2 * A, B], [B, 2 * C]]), [-D, -E])
    values, vectors = np.linalg.eigh(np.array([[A, B / 2], [B / 2, C]]))
    F0 = F + (D * centre[0] + E * centre[1]) / 2.0
    u = vectors[:, 0] if vectors[0, 0] > 0 else -vectors[:, 0]
    return centre, np.sqrt(-F0 / values[0]), np.sqrt(-F0 / values[1]), u


def test_fits_equal_the_plain_formulation():
    """The in-place swarm and the LAPACK calls give the plain formulation's numbers: the
    same random draws and floating-point operations in the same order (bit for bit on
    one machine; 1e-10 allows numpy's and scipy's LAPACK builds, and OpenBLAS's kernels for
    other processors, to round differently: 1.4e-12 was seen on a Xeon where it was 0 elsewhere)."""
    rng = np.random.default_rng(7)
    cases = [ellipse_points(n=8)[0] + rng.normal(0, 1.0, (8, 2))]
    cases += [rng.normal(0, 1, (8, 2)) * rng.uniform(5, 200) + rng.uniform(0, 640, 2) for _ in range(8)]
    for points in cases:
        p, mean, scale = _normalise(points)
        np.testing.assert_allclose(direct_conic(p), _plain_direct(p), rtol=0, atol=1e-10)
        conic = pso_conic(p)
        np.testing.assert_allclose(conic, _plain_pso(p), rtol=0, atol=1e-10)
        centre, a, b, u = _plain_geometry(conic)
        e = fit_ellipse(points)
        np.testing.assert_allclose(e.centre, centre * scale + mean, rtol=1e-12)
        np.testing.assert_allclose([e.a, e.b], [a * scale, b * scale], rtol=1e-12)
        np.testing.assert_allclose(e.u, u, atol=1e-12)

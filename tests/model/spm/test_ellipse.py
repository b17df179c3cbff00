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

"""spm_model.spm.manifold: the foci-distance vector, its canonical orders and invariances, and the
appended ellipse parameters."""

import numpy as np
import pytest

from spm_model.spm.ellipse import Ellipse, fit_ellipse
from spm_model.spm.manifold import canonical_order, foci_distances, initial_manifold
from tests.helpers import ellipse_points


def test_manifold_is_unit_length_canonical_and_translation_scale_invariant():
    pts, _ = ellipse_points(n=8, phase=0.1)
    m, ecc = initial_manifold(pts, "direct")
    assert m.shape == (16,) and np.linalg.norm(m) == pytest.approx(1.0) and 0 < ecc < 1
    shuffled = pts[np.random.default_rng(0).permutation(8)]
    np.testing.assert_allclose(initial_manifold(shuffled, "direct")[0], m, atol=1e-9)
    moved = pts * 2.5 + np.array([100.0, -30.0])
    np.testing.assert_allclose(initial_manifold(moved, "direct")[0], m, atol=1e-9)
    # Pairs: the two distances of a point on the ellipse add up to 2a (normalised alike).
    pairs = m.reshape(8, 2).sum(axis=1)
    np.testing.assert_allclose(pairs, pairs[0], rtol=1e-9)


def test_canonical_order_follows_angle_from_the_major_axis():
    e = Ellipse(np.zeros(2), 2.0, 1.0, np.array([1.0, 0.0]))
    centres = np.array([[0, 1.0], [-2, 0], [2, 0.0], [0, -1.0]])  # +90, 180, 0, 270 degrees
    assert list(canonical_order(centres, e)) == [2, 0, 1, 3]
    d = foci_distances(centres, e)
    c = np.sqrt(3.0)
    raw = np.array([2 + c, 2 - c, 2, 2, 2 - c, 2 + c, 2, 2])  # (+2,0), (0,1), (-2,0), (0,-1) to (-c,0), (c,0)
    np.testing.assert_allclose(d, raw / np.linalg.norm(raw))


def test_cluster_orders_and_unnormalised_vector():
    pts, _ = ellipse_points(centre=(0.0, 0.0), a=30.0, b=18.0, degrees=0.0, n=8, phase=0.3)
    e = Ellipse(np.zeros(2), 30.0, 18.0, np.array([1.0, 0.0]))
    # angle: around the centroid from +x towards +y; here the points were made in that order.
    np.testing.assert_array_equal(canonical_order(pts, e, "angle"), np.arange(8))
    # distance: nearest to the ellipse centre first.
    r = np.linalg.norm(pts, axis=1)
    np.testing.assert_array_equal(canonical_order(pts, e, "distance"), np.argsort(r, kind="stable"))
    with pytest.raises(ValueError, match="order must be"):
        canonical_order(pts, e, "nope")
    raw = foci_distances(pts, e, normalise=False)
    c = np.sqrt(30.0 ** 2 - 18.0 ** 2)
    first = pts[canonical_order(pts, e)[0]]
    np.testing.assert_allclose(raw[:2], [np.hypot(first[0] + c, first[1]), np.hypot(first[0] - c, first[1])])
    np.testing.assert_allclose(raw / np.linalg.norm(raw), foci_distances(pts, e))
    # On an ellipse, the two distances of every point sum to 2a.
    np.testing.assert_allclose(raw.reshape(-1, 2).sum(axis=1), 60.0)


def test_distances_ignore_in_plane_rotation_and_mirroring():
    pts, _ = ellipse_points(n=8)
    pts = pts + np.random.default_rng(3).normal(0, 1.0, pts.shape)
    base = np.sort(foci_distances(pts, fit_ellipse(pts, "direct")))
    for degrees in (17.0, 90.0, 200.0):
        t = np.radians(degrees)
        rot = pts @ np.array([[np.cos(t), -np.sin(t)], [np.sin(t), np.cos(t)]]).T
        np.testing.assert_allclose(np.sort(foci_distances(rot, fit_ellipse(rot, "direct"))), base, atol=1e-9)
    mirrored = pts * np.array([-1.0, 1.0])
    np.testing.assert_allclose(np.sort(foci_distances(mirrored, fit_ellipse(mirrored, "direct"))), base, atol=1e-9)


def test_append_ellipse_parameters():
    from spm_model.spm.manifold import ellipse_parameters

    e = Ellipse(np.zeros(2), 30.0, 15.0, np.array([np.cos(np.radians(30)), np.sin(np.radians(30))]))
    np.testing.assert_allclose(ellipse_parameters(e), [0.5, np.cos(np.radians(60)), np.sin(np.radians(60))])
    pts, _ = ellipse_points(n=8)
    v, ecc = initial_manifold(pts, method="direct", append_ellipse=True)
    v0, ecc0 = initial_manifold(pts, method="direct")
    assert v.shape == (19,) and ecc == ecc0
    np.testing.assert_array_equal(v[:16], v0)
    np.testing.assert_allclose(v[16:], [18.0 / 30.0, np.cos(np.radians(60)), np.sin(np.radians(60))], atol=1e-7)

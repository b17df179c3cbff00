"""spm_model.spm.bunches: EM finds known clusters of keypoints, seeded; too few keypoints are refused."""

import numpy as np
import pytest

from spm_model.spm.bunches import BunchError, fit_bunches


def test_em_recovers_known_clusters():
    rng = np.random.default_rng(3)
    true = np.array([[20, 20], [60, 25], [100, 20], [20, 70], [60, 65], [100, 75], [35, 110], [90, 110.0]])
    pts = np.concatenate([m + rng.normal(0, 3.0, (25, 2)) for m in true])
    b = fit_bunches(pts, gamma=8, seed=1)
    assert b.means.shape == (8, 2) and b.weights.sum() == pytest.approx(1.0)
    error = np.min(np.linalg.norm(b.means[:, None] - true[None], axis=2), axis=0)  # each true centre found
    assert error.max() < 2.0
    again = fit_bunches(pts, gamma=8, seed=1)
    np.testing.assert_array_equal(again.means, b.means)  # seeded: repeatable


def test_too_few_keypoints_are_refused():
    with pytest.raises(BunchError, match="15 keypoints is too few for 8 clusters"):
        fit_bunches(np.random.default_rng(0).random((15, 2)))


def textbook_em(x, gamma, seed, tol=1e-2, max_iter=100, ridge=0.25):
    """EM written point by point from Eq. 8-9, with fit_bunches' seeding, ridge and stopping rule."""
    from spm_model.spm.bunches import _kmeans_pp

    means = _kmeans_pp(x, gamma, np.random.default_rng(seed))
    covs = np.repeat((np.cov(x.T) / gamma + ridge * np.eye(2))[None], gamma, axis=0)
    weights = np.full(gamma, 1.0 / gamma)
    for it in range(1, max_iter + 1):
        dens = np.stack([w * np.exp(-0.5 * np.einsum("ni,ij,nj->n", x - m, np.linalg.inv(S), x - m))
                         / (2 * np.pi * np.sqrt(np.linalg.det(S))) for m, S, w in zip(means, covs, weights)], axis=1)
        resp = dens / dens.sum(axis=1, keepdims=True)
        nk = resp.sum(axis=0) + 1e-12
        new = (resp.T @ x) / nk[:, None]
        covs = np.array([(resp[:, k, None] * (x - new[k])).T @ (x - new[k]) / nk[k] + ridge * np.eye(2)
                         for k in range(gamma)])
        weights, moved, means = nk / len(x), np.abs(new - means).max(), new
        if moved < tol:
            break
    return means, covs, weights, it


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_em_equals_the_textbook_em(seed):
    rng = np.random.default_rng(seed)
    pts = np.concatenate([rng.normal(c, s, (30, 2)) for c, s in zip(rng.uniform(20, 230, (8, 2)), rng.uniform(2, 12,
                                                                                                              8))])
    b = fit_bunches(pts, gamma=8, seed=seed)
    means, covs, weights, iterations = textbook_em(pts, 8, seed)
    assert b.iterations == iterations
    np.testing.assert_allclose(b.means, means, atol=1e-6)
    np.testing.assert_allclose(b.covariances, covs, atol=1e-6)
    np.testing.assert_allclose(b.weights, weights, atol=1e-9)

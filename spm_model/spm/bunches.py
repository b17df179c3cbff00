"""The bunch-based structure (paper §2.1, Algorithm 1, Appendix): EM on a Gaussian
mixture of the 2-D keypoint locations, gamma = 8 clusters by default.

Pure numpy: k-means++ seeding from a seeded generator, then EM with full
covariances (a small ridge keeps them invertible) until the parameters move
less than ``tol`` pixels. Frames with fewer than ``2 * gamma`` keypoints are
refused with BunchError, never zero-filled.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from spm_data.errors import BunchError


GAMMA = 8


@dataclass(frozen=True)
class Bunches:
    """means (gamma, 2) pixels; covariances (gamma, 2, 2); weights (gamma,) summing to 1."""

    means: np.ndarray
    covariances: np.ndarray
    weights: np.ndarray
    iterations: int


def _kmeans_pp(x, k, rng):
    centres = [x[rng.integers(len(x))]]
    for _ in range(1, k):
        d2 = np.min(((x[:, None, :] - np.array(centres)[None]) ** 2).sum(axis=2), axis=1)
        total = d2.sum()
        centres.append(x[rng.choice(len(x), p=d2 / total)] if total > 0 else x[rng.integers(len(x))])
    return np.array(centres)


def _log_gauss(x, means, covs):
    """(N, k) log densities of (N, 2) points under k 2-D Gaussians; closed-form 2x2
    inverses and determinants (LAPACK per 2x2 matrix dominated the run time)."""
    return _log_gauss_xy(x[:, 0][:, None], x[:, 1][:, None], means, covs[:, 0, 0], covs[:, 0, 1], covs[:, 1, 1])


def _log_gauss_xy(px, py, means, a, b, c):
    """_log_gauss from the points' columns px, py (N, 1) and the covariances' entries
    a = s_xx, b = s_xy, c = s_yy (k,): the same arithmetic, fewer temporaries."""
    det = a * c - b * b
    d0, d1 = px - means[:, 0], py - means[:, 1]  # (N, k)
    quad = (c * d0 ** 2 - 2 * b * d0 * d1 + a * d1 ** 2) / det
    return -0.5 * (quad + np.log(det) + 2 * np.log(2 * np.pi))


def fit_bunches(locations, gamma: int = GAMMA, seed: int = 0, tol: float = 1e-2, max_iter: int = 100,
                ridge: float = 0.25) -> Bunches:
    """EM (Algorithm 1) on (N, 2) keypoint locations; N must be >= 2 * gamma."""
    x = np.asarray(locations, dtype=np.float64)
    if x.ndim != 2 or x.shape[1] != 2:
        raise BunchError(f"expected (N, 2) keypoint locations, got shape {x.shape}")
    if len(x) < 2 * gamma:
        raise BunchError(f"{len(x)} keypoints is too few for {gamma} clusters (need at least {2 * gamma})")
    rng = np.random.default_rng(seed)
    means = _kmeans_pp(x, gamma, rng)
    spread = np.cov(x.T) / gamma + ridge * np.eye(2)
    covs = np.repeat(spread[None], gamma, axis=0)
    weights = np.full(gamma, 1.0 / gamma)
    px, py = x[:, 0][:, None], x[:, 1][:, None]
    a, b, c = covs[:, 0, 0], covs[:, 0, 1], covs[:, 1, 1]
    for it in range(1, max_iter + 1):  # noqa: B007 - the count is reported after the loop
        # E-step: P(b_k | v) for every keypoint (log-sum-exp for stability).
        log_p = np.log(weights) + _log_gauss_xy(px, py, means, a, b, c)
        log_p -= log_p.max(axis=1, keepdims=True)
        resp = np.exp(log_p)
        resp /= resp.sum(axis=1, keepdims=True)
        # M-step: Eq. 8 for the means and covariances, Eq. 9 for the priors.
        nk = resp.sum(axis=0) + 1e-12
        new_means = (resp.T @ x) / nk[:, None]
        dx, dy = px - new_means[:, 0], py - new_means[:, 1]  # (N, k)
        sxx, sxy, syy = ((resp * dx * dx).sum(0), (resp * dx * dy).sum(0), (resp * dy * dy).sum(0))
        a, b, c = sxx / nk + ridge, sxy / nk + 0.0, syy / nk + ridge
        weights = nk / len(x)
        moved = np.abs(new_means - means).max()
        means = new_means
        if moved < tol:
            break
    covs = np.stack([np.stack([a, b], -1), np.stack([b, c], -1)], -2)
    return Bunches(means=means, covariances=covs, weights=weights, iterations=it)

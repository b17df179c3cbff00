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

from spm_model.errors import BunchError


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


LOG_2PI = float(np.log(2 * np.pi))


def _log_density_coefficients(coef, mx, my, a, b, c, log_weights) -> None:
    """Fill ``coef`` (k, 6) so that log(w_k N(v | mu_k, S_k)) = coef[k] @ [1, x, y, x^2, xy, y^2]
    for v = (x, y): means (mx, my), covariance entries a = s_xx, b = s_xy, c = s_yy and log
    weights, all (k,). One matrix product then scores every point under every cluster
    (numpy's per-call overhead, not arithmetic, dominated the element-wise form)."""
    det = a * c - b * b
    h = -0.5 / det  # log N = -(c dx^2 - 2b dx dy + a dy^2) / (2 det) - log(det) / 2 - log(2 pi)
    hc, hb, ha = h * c, h * b, h * a
    coef[:, 0] = hc * mx * mx - 2 * hb * mx * my + ha * my * my + log_weights - 0.5 * np.log(det) - LOG_2PI
    coef[:, 1] = 2 * (hb * my - hc * mx)
    coef[:, 2] = 2 * (hb * mx - ha * my)
    coef[:, 3], coef[:, 4], coef[:, 5] = hc, -2 * hb, ha


def fit_bunches(locations, gamma: int = GAMMA, seed: int = 0, tol: float = 1e-2, max_iter: int = 100,
                ridge: float = 0.25) -> Bunches:
    """EM (Algorithm 1) on (N, 2) keypoint locations; N must be >= 2 * gamma."""
    x = np.asarray(locations, dtype=np.float64)
    if x.ndim != 2 or x.shape[1] != 2:
        raise BunchError(f"expected (N, 2) keypoint locations, got shape {x.shape}")
    if len(x) < 2 * gamma:
        raise BunchError(f"{len(x)} keypoints is too few for {gamma} clusters (need at least {2 * gamma})")
    n = len(x)
    rng = np.random.default_rng(seed)
    origin = x.mean(axis=0)  # centred coordinates keep the moments below well conditioned
    means = _kmeans_pp(x, gamma, rng) - origin
    mx, my = means[:, 0].copy(), means[:, 1].copy()
    spread = np.cov(x.T) / gamma + ridge * np.eye(2)
    a, b, c = np.full(gamma, spread[0, 0]), np.full(gamma, spread[0, 1]), np.full(gamma, spread[1, 1])
    log_weights = np.full(gamma, np.log(1.0 / gamma))
    px, py = x[:, 0] - origin[0], x[:, 1] - origin[1]
    powers = np.stack([np.ones(n), px, py, px * px, px * py, py * py])  # (6, N)
    coef = np.empty((gamma, 6))
    for it in range(1, max_iter + 1):  # noqa: B007 - the count is reported after the loop
        # E-step: P(b_k | v) for every keypoint, (k, N) (log-sum-exp for stability).
        _log_density_coefficients(coef, mx, my, a, b, c, log_weights)
        resp = coef @ powers
        resp -= resp.max(axis=0)
        np.exp(resp, out=resp)
        resp /= resp.sum(axis=0)
        # M-step: Eq. 8 for the means and covariances, Eq. 9 for the priors, from the
        # responsibility-weighted moments (k, 6): sums of 1, x, y, x^2, xy, y^2.
        m = resp @ powers.T
        nk = m[:, 0] + 1e-12
        new_x, new_y = m[:, 1] / nk, m[:, 2] / nk
        a = (m[:, 3] - new_x * (2 * m[:, 1] - new_x * m[:, 0])) / nk + ridge
        b = (m[:, 4] - new_x * m[:, 2] - new_y * m[:, 1] + new_x * new_y * m[:, 0]) / nk
        c = (m[:, 5] - new_y * (2 * m[:, 2] - new_y * m[:, 0])) / nk + ridge
        log_weights = np.log(nk / n)
        moved = max(np.abs(new_x - mx).max(), np.abs(new_y - my).max())
        mx, my = new_x, new_y
        if moved < tol:
            break
    weights = nk / n
    means = np.column_stack([mx, my]) + origin
    covs = np.stack([np.stack([a, b], -1), np.stack([b, c], -1)], -2)
    return Bunches(means=means, covariances=covs, weights=weights, iterations=it)

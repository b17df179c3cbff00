"""The initial pose manifold (paper §2.2, §3.1): distances of the cluster centres to the
ellipse's two foci, 2 x gamma values in a canonical order, normalised to unit length.

Cluster order and which focus comes first are otherwise arbitrary; both come from
the ellipse's geometry: the foci in the order behind/ahead along the major-axis
direction u (u points to +x in the image, or +y if vertical), and the clusters by
their angle around the ellipse's centre, measured from u towards the image's +y.
The vector is invariant to translating and scaling the image, not to rotating it
(an in-plane rotation is part of the pose).
"""

from __future__ import annotations

import numpy as np

from spm_model.ellipse import LAMBDA, Ellipse, fit_ellipse


def canonical_order(centres: np.ndarray, ellipse: Ellipse) -> np.ndarray:
    """Indices of (gamma, 2) cluster centres sorted by angle from u around the ellipse centre."""
    d = np.asarray(centres, dtype=np.float64) - ellipse.centre
    u = ellipse.u
    angle = np.arctan2(u[0] * d[:, 1] - u[1] * d[:, 0], d @ u) % (2 * np.pi)
    return np.argsort(angle, kind="stable")


def foci_distances(centres: np.ndarray, ellipse: Ellipse) -> np.ndarray:
    """(2 * gamma,) float64 unit vector: for each cluster in canonical order, its
    distances to the first and the second focus."""
    centres = np.asarray(centres, dtype=np.float64)
    f = ellipse.foci
    ordered = centres[canonical_order(centres, ellipse)]
    distances = np.linalg.norm(ordered[:, None, :] - f[None, :, :], axis=2).ravel()
    norm = np.linalg.norm(distances)
    return distances / norm if norm > 0 else distances


def initial_manifold(centres: np.ndarray, method: str = "pso", seed: int = 0,
                     lam: float = LAMBDA) -> tuple[np.ndarray, float]:
    """Fit the ellipse over (gamma, 2) cluster centres (pixels); returns the
    (2 * gamma,) manifold vector and the ellipse's eccentricity (paper Table 1)."""
    ellipse = fit_ellipse(centres, method=method, lam=lam, seed=seed)
    return foci_distances(centres, ellipse), ellipse.eccentricity

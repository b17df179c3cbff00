"""The initial pose manifold (paper §2.2, §3.1): distances of the cluster centres to the
ellipse's two foci, 2 x gamma values in a canonical order, normalised to unit length.

Cluster order and which focus comes first are otherwise arbitrary; by default
(``order="sign"``) both come from the ellipse's geometry: the foci in the order
behind/ahead along the major-axis direction u (u points to +x in the image, or
+y if vertical), and the clusters by their angle around the ellipse's centre,
measured from u towards the image's +y. Two alternative cluster orders (the
paper leaves the order open; benchmarks/spm_ablation.py sweeps them), with the
same foci order: ``"angle"``, by the angle around the centres' centroid measured
from the image's +x axis towards +y, and ``"distance"``, by the distance from the
ellipse's centre (nearest first).

What the vector encodes: the distances themselves are unchanged by translating,
scaling (after the unit normalisation), rotating or mirroring the centres (the
ellipse fit follows the centres, and distances are unchanged by any isometry;
exactly so for the direct fit, up to the swarm's tolerance for PSO). So an
in-plane rotation of the image is NOT encoded by the distance values; at most
the cluster and focus order, which the rules above tie to the image axes, turn
into a permutation of the same values. ``ellipse_parameters`` (opt-in) appends
the ellipse's axis ratio and major-axis orientation, which do change with an
in-plane rotation.
"""

from __future__ import annotations

import math

import numpy as np

from spm_model.spm.ellipse import LAMBDA, Ellipse, fit_ellipse

ORDERS = ("sign", "angle", "distance")


def canonical_order(centres: np.ndarray, ellipse: Ellipse, order: str = "sign") -> np.ndarray:
    """Indices of (gamma, 2) cluster centres in the ``order`` rule's sequence (see the
    module docstring; "sign", the default: by angle from u around the ellipse centre)."""
    centres = np.asarray(centres, dtype=np.float64)
    if order == "sign":
        d = centres - ellipse.centre
        u0, u1 = ellipse.u.tolist()
        angle = np.arctan2(u0 * d[:, 1] - u1 * d[:, 0], d @ ellipse.u)
        angle %= 2 * np.pi
        return angle.argsort(kind="stable")
    if order == "angle":
        d = centres - centres.mean(axis=0)
        return np.argsort(np.arctan2(d[:, 1], d[:, 0]) % (2 * np.pi), kind="stable")
    if order == "distance":
        return np.argsort(np.linalg.norm(centres - ellipse.centre, axis=1), kind="stable")
    raise ValueError(f"order must be one of {ORDERS}, got {order!r}")


def foci_distances(centres: np.ndarray, ellipse: Ellipse, order: str = "sign", normalise: bool = True) -> np.ndarray:
    """(2 * gamma,) float64 vector: for each cluster in ``order``, its distances to
    the first and the second focus; a unit vector unless ``normalise`` is False
    (then in the centres' units, pixels)."""
    centres = np.asarray(centres, dtype=np.float64)
    ordered = centres[canonical_order(centres, ellipse, order)]
    diff = ordered[:, None, :] - ellipse.foci[None, :, :]
    # np.linalg.norm's own operations (axis=2; then x.dot(x)), without its wrapper's overhead
    distances = np.sqrt(np.add.reduce(diff * diff, 2)).ravel()
    if not normalise:
        return distances
    norm = math.sqrt(distances.dot(distances))
    return distances / norm if norm > 0 else distances


def ellipse_parameters(ellipse: Ellipse) -> np.ndarray:
    """(3,) float64: axis ratio b / a, and cos 2 theta, sin 2 theta of the major
    axis's angle theta from the image's +x axis (continuous across u's sign flip);
    invariant to translation and scale, not to in-plane rotation."""
    theta = np.arctan2(ellipse.u[1], ellipse.u[0])
    return np.array([ellipse.b / ellipse.a, np.cos(2 * theta), np.sin(2 * theta)])


def initial_manifold(centres: np.ndarray, method: str = "pso", seed: int = 0,
                     lam: float = LAMBDA, order: str = "sign", normalise: bool = True,
                     append_ellipse: bool = False) -> tuple[np.ndarray, float]:
    """Fit the ellipse over (gamma, 2) cluster centres (pixels); returns the
    (2 * gamma,) manifold vector (``foci_distances`` with ``order`` and
    ``normalise``; with ``append_ellipse``, followed by ``ellipse_parameters``:
    (2 * gamma + 3,)) and the ellipse's eccentricity (paper Table 1)."""
    ellipse = fit_ellipse(centres, method=method, lam=lam, seed=seed)
    vector = foci_distances(centres, ellipse, order=order, normalise=normalise)
    if append_ellipse:
        vector = np.concatenate([vector, ellipse_parameters(ellipse)])
    return vector, ellipse.eccentricity

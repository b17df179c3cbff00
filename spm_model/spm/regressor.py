"""RBF-kernel regressor from re-projected vectors to the 6-DoF label (paper §2.4, Appendix).

Kernel ridge regression with a Gaussian (RBF) kernel, trained with input noise
as in the Appendix (each training vector is repeated ``noise_copies`` times with
Gaussian noise of standard deviation ``noise``, which approximates Tikhonov
regularisation). Angles wrap: each of rx, ry, rz is regressed as (cos, sin) and
read back with atan2, so 359 and 1 degrees are neighbours; translation is
regressed as is. Exact kernel ridge costs O(n^3); above ``landmarks`` training
vectors (after the noise copies) it becomes the Nystrom / subset-of-regressors
solution on ``landmarks`` random centres, ``min ||K_nm c - Z||^2 + alpha c^T K_mm c``,
which equals exact kernel ridge when the centres are all the vectors. Follows scikit-learn's estimator contract
(keyword-only
parameters stored as given, ``fit`` returns self, learned state ends in ``_``; an unfitted
regressor raises ModelError, spm_model/base/estimator.py). ``from_state`` rebuilds a fitted
regressor from its learned attributes (how a model file is read).
"""

from __future__ import annotations

import numpy as np

from spm_model.base.estimator import Estimator, check_fitted


def _targets(y: np.ndarray) -> np.ndarray:
    """(n, 6) labels -> (n, 9): cos/sin of the three angles (degrees), then t."""
    a = np.radians(y[:, :3])
    return np.column_stack([np.cos(a), np.sin(a), y[:, 3:]])


def _labels(z: np.ndarray) -> np.ndarray:
    angles = np.degrees(np.arctan2(z[:, 3:6], z[:, 0:3]))
    return np.column_stack([angles, z[:, 6:9]])


class RBFPoseRegressor(Estimator):
    """Kernel ridge regressor with an RBF kernel ``exp(-kernel_coef_ ||x - x'||^2)``;
    ``kernel_coef=None`` uses the median heuristic, ``kernel_coef_ = 1 / (width_scale * median
    squared distance)``: ``width_scale`` > 1 widens the kernel (it is ignored when
    ``kernel_coef`` is given). ``landmarks``: the Nystrom centres (see the module docstring).
    Learned: ``kernel_coef_``, ``X_fit_`` (the centres), ``dual_coef_`` (m, 9), ``mean_`` (9,)."""

    FITTED = ("kernel_coef_", "X_fit_", "dual_coef_", "mean_")

    def __init__(self, *, kernel_coef: float | None = None, alpha: float = 1e-3, noise: float = 0.0,
                 noise_copies: int = 0, landmarks: int = 2000, seed: int = 0, width_scale: float = 1.0):
        self.kernel_coef = kernel_coef
        self.width_scale = width_scale
        self.alpha = alpha
        self.noise = noise
        self.noise_copies = noise_copies
        self.landmarks = landmarks
        self.seed = seed


    def _kernel(self, A, B):
        d2 = (A ** 2).sum(1)[:, None] + (B ** 2).sum(1)[None, :] - 2 * A @ B.T
        return np.exp(-self.kernel_coef_ * np.maximum(d2, 0.0))

    def fit(self, X, y) -> "RBFPoseRegressor":
        X = np.asarray(X, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        if X.ndim != 2 or y.ndim != 2 or y.shape[1] != 6 or len(X) != len(y):
            raise ValueError(f"expected X (n, d) and y (n, 6) with the same n; got X {X.shape}, y {y.shape}; "
                             "y holds (rx, ry, rz, tx, ty, tz) labels")
        if not self.width_scale > 0:
            raise ValueError(f"width_scale must be > 0, got {self.width_scale}")
        if not (np.isfinite(X).all() and np.isfinite(y).all()):
            raise ValueError("X and y must be finite; drop frames whose features failed")
        Z = _targets(y)
        if self.noise > 0 and self.noise_copies > 0:
            rng = np.random.default_rng(self.seed)
            noisy = [X + rng.normal(0, self.noise, X.shape) for _ in range(self.noise_copies)]
            X, Z = np.vstack([X, *noisy]), np.vstack([Z] * (self.noise_copies + 1))
        if self.kernel_coef is None:
            rng = np.random.default_rng(self.seed)
            sample = X[rng.choice(len(X), size=min(len(X), 500), replace=False)]
            d2 = ((sample[:, None] - sample[None]) ** 2).sum(axis=2)
            median = np.median(d2[d2 > 0]) if (d2 > 0).any() else 1.0
            self.kernel_coef_ = 1.0 / (self.width_scale * median)
        else:
            self.kernel_coef_ = float(self.kernel_coef)
        self.mean_ = Z.mean(axis=0)
        if len(X) <= self.landmarks:
            K = self._kernel(X, X)
            self.dual_coef_ = np.linalg.solve(K + self.alpha * np.eye(len(X)), Z - self.mean_)
            self.X_fit_ = X
        else:
            centres = X[np.random.default_rng(self.seed).choice(len(X), self.landmarks, replace=False)]
            A = self.alpha * self._kernel(centres, centres)
            b = np.zeros((self.landmarks, Z.shape[1]))
            for start in range(0, len(X), 8192):  # K_nm in blocks: bounded memory at any n
                K = self._kernel(X[start:start + 8192], centres)
                A += K.T @ K
                b += K.T @ (Z[start:start + 8192] - self.mean_)
            A[np.diag_indices_from(A)] += 1e-8 * np.trace(A) / len(A)
            self.dual_coef_ = np.linalg.solve(A, b)
            self.X_fit_ = centres
        return self

    def predict(self, X) -> np.ndarray:
        """(n, d) -> (n, 6) labels: angles in (-180, 180] degrees, t in metres."""
        check_fitted(self, self.FITTED)
        X = np.asarray(X, dtype=np.float64)
        if X.ndim != 2 or X.shape[1] != self.X_fit_.shape[1]:
            raise ValueError(f"expected X with {self.X_fit_.shape[1]} columns, got shape {X.shape}")
        return _labels(self._kernel(X, self.X_fit_) @ self.dual_coef_ + self.mean_)

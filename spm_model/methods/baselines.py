"""Baselines beside SPM, on the same splits (paper §3.3-3.4):

- ``KNNPose``: K nearest neighbours (Table 2) on the same training matrix as
  the regressor (the re-projected vectors); K > 1 averages the neighbours'
  angles on the circle (via cos/sin) and their translations.
- ``PCAPose``: appearance-based, on raw image vectors (the grey object box
  resized to a small square, zero mean and unit norm per image): PCA, then the
  nearest training image in the PCA subspace (Murase & Nayar's scheme).
- ``LSPose``: a linear least-squares (ridge) map from the raw image vectors to
  the label, angles as cos/sin as in the regressor.

All follow scikit-learn's contract: keyword-only parameters, ``fit`` returns self,
learned state ends in ``_`` (``FITTED``); predict before fit raises ModelError
(spm_model/base/estimator.py).
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import eigh
from scipy.spatial import cKDTree

from spm_model.errors import ModelError
from spm_model.base.estimator import Estimator, PoseEstimator, check_fitted
from spm_model.base.frames import column
from spm_model.base.images import raw_vector
from spm_model.spm.regressor import _labels, _targets


def _mean_labels(labels: np.ndarray) -> np.ndarray:
    """(n, k, 6) neighbour labels -> (n, 6): circular mean of angles, mean of t."""
    z = _targets(labels.reshape(-1, 6)).reshape(labels.shape[0], labels.shape[1], 9).mean(axis=1)
    return _labels(z)


class KNNPose(Estimator):
    """The mean label of the ``k`` nearest training vectors (angles on the circle)."""

    FITTED = ("tree_", "y_")

    def __init__(self, *, k: int = 1):
        self.k = k

    def fit(self, X, y) -> "KNNPose":
        self.tree_ = cKDTree(np.asarray(X, dtype=np.float64))
        self.y_ = np.asarray(y, dtype=np.float64)
        return self

    def predict(self, X) -> np.ndarray:
        check_fitted(self, self.FITTED)
        k = min(self.k, len(self.y_))
        _, idx = self.tree_.query(np.asarray(X, dtype=np.float64), k=k)
        return _mean_labels(self.y_[np.asarray(idx).reshape(len(X), k)])


def _unit_rows(raw) -> np.ndarray:
    x = np.asarray(raw, dtype=np.float64)
    x = x - x.mean(axis=1, keepdims=True)
    return x / np.maximum(np.linalg.norm(x, axis=1, keepdims=True), 1e-12)


def _fit_centred(raw) -> tuple[np.ndarray, np.ndarray]:
    """Training raw vectors -> (per-pixel mean of the unit rows, the rows minus it)."""
    x = _unit_rows(raw)
    mean = x.mean(axis=0)
    return mean, x - mean


class PCAPose(Estimator):
    """Nearest training image in the top ``components`` principal axes of the unit raw vectors."""

    FITTED = ("mean_", "basis_", "knn_")

    def __init__(self, *, components: int = 20):
        self.components = components

    def fit(self, raw, y) -> "PCAPose":
        self.mean_, xc = _fit_centred(raw)
        d = xc.shape[1]
        k = min(self.components, d, len(xc))
        # Top eigenvectors of the (d x d) scatter: far cheaper than an SVD of (n x d) for n >> d.
        _, vectors = eigh(xc.T @ xc, subset_by_index=[d - k, d - 1])
        self.basis_ = vectors[:, ::-1]
        self.knn_ = KNNPose(k=1).fit(xc @ self.basis_, y)
        return self

    def predict(self, raw) -> np.ndarray:
        check_fitted(self, self.FITTED)
        return self.knn_.predict((_unit_rows(raw) - self.mean_) @ self.basis_)


class LSPose(Estimator):
    """Ridge regression (``alpha``) from the unit raw vectors to the label, angles as cos/sin."""

    FITTED = ("mean_", "target_mean_", "coef_")

    def __init__(self, *, alpha: float = 1.0):
        self.alpha = alpha

    def fit(self, raw, y) -> "LSPose":
        self.mean_, xc = _fit_centred(raw)
        z = _targets(np.asarray(y, dtype=np.float64))
        self.target_mean_ = z.mean(axis=0)
        self.coef_ = np.linalg.solve(xc.T @ xc + self.alpha * np.eye(xc.shape[1]), xc.T @ (z - self.target_mean_))
        return self

    def predict(self, raw) -> np.ndarray:
        check_fitted(self, self.FITTED)
        return _labels((_unit_rows(raw) - self.mean_) @ self.coef_ + self.target_mean_)


class RawImagePose(PoseEstimator):
    """The paper's appearance baselines on 32 x 32 grey object boxes:
    ``kind = "pca"`` (PCA + nearest neighbour) or ``"ls"`` (least squares)."""

    FITTED = ("model_",)
    DETERMINISTIC = True   # no seed; each frame's code and pose are its own

    def __init__(self, *, kind: str = "pca", size: int = 32):
        self.kind = kind
        self.size = size

    def _raw(self, frames):
        return column(frames, "raw", lambda f: raw_vector(f["rgb"], f["mask"], self.size))

    def fit(self, frames, poses) -> "RawImagePose":
        if self.kind not in ("pca", "ls"):
            raise ModelError(f"kind must be 'pca' or 'ls', got {self.kind!r}")
        model = PCAPose() if self.kind == "pca" else LSPose()
        self.model_ = model.fit(self._raw(frames), np.asarray(poses, np.float64))
        return self

    def predict(self, frames) -> np.ndarray:
        check_fitted(self, self.FITTED)
        return self.model_.predict(self._raw(frames))


class ChancePose(PoseEstimator):
    """The pose of a random training frame (seeded): the floor every method must beat."""

    FITTED = ("poses_",)

    def __init__(self, *, seed: int = 0):
        self.seed = seed

    def fit(self, frames, poses) -> "ChancePose":
        self.poses_ = np.asarray(poses, dtype=np.float64)
        return self

    def predict(self, frames) -> np.ndarray:
        check_fitted(self, self.FITTED)
        rng = np.random.default_rng(self.seed)
        return self.poses_[rng.integers(0, len(self.poses_), len(frames))]

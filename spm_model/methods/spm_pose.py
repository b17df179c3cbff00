"""SPM as a benchmark method: the SPM estimator (spm_model/spm/estimator.py) on frames,
and KNN on its re-projected vectors (the paper's Table 2)."""

from __future__ import annotations

import numpy as np

from spm_model.errors import FeatureError, ModelError
from spm_model.base.estimator import Needs, PoseEstimator, check_fitted, is_fitted
from spm_model.base.frames import column
from spm_model.methods.baselines import KNNPose
from spm_model.spm.estimator import SPMEstimator
from spm_model.spm.features import FeatureConfig, image_features

MIN_TRAIN_FRAMES = 10


def _spm_vector(frame, config: FeatureConfig) -> np.ndarray:
    try:
        return image_features(frame["rgb"], frame["mask"], config, raw=False)["vector"]
    except FeatureError:
        return np.full(config.dims, np.nan)


class SPMPose(PoseEstimator):
    """SPM (spm_model/spm/estimator.py) on frames: training frames use their cached
    ``train_vector`` (the path-neighbour keypoint rule) when the sequence has
    it, test frames their ``query_vector``; without a cache, features are
    computed from each image by the query rule. Frames without a feature are
    left out of training and get NaN."""

    FITTED = ("model_",)
    NEEDS = Needs(spm_features=MIN_TRAIN_FRAMES)

    def __init__(self, *, seed: int = 0, features: FeatureConfig = FeatureConfig(), params: dict | None = None):
        self.seed = seed
        self.features = features
        self.params = params

    def vectors(self, frames, kind: str) -> np.ndarray:
        return column(frames, f"{kind}_vector", lambda f: _spm_vector(f, self.features))

    def features_found(self, frames) -> np.ndarray:
        """(n,) bool: the frames with SPM query features (SIFT found enough keypoints for the ellipse)."""
        return np.isfinite(self.vectors(frames, "query")).all(axis=1)

    def fit(self, frames, poses) -> "SPMPose":
        X, y = self.vectors(frames, "train"), np.asarray(poses, dtype=np.float64)
        ok = np.isfinite(X).all(axis=1)
        if ok.sum() < MIN_TRAIN_FRAMES:
            raise ModelError(f"only {int(ok.sum())} training frames have SPM features (need {MIN_TRAIN_FRAMES}); "
                             "render more views or larger images")
        self.model_ = SPMEstimator(**(self.params or {}), features=self.features, seed=self.seed).fit(X[ok], y[ok])
        return self

    def predict(self, frames) -> np.ndarray:
        check_fitted(self, self.FITTED)
        X = self.vectors(frames, "query")
        ok = np.isfinite(X).all(axis=1)
        out = np.full((len(X), 6), np.nan)
        if ok.any():
            out[ok] = self.model_.predict(X[ok])
        return out

    def save(self, path):
        """Its SPM estimator's model file (spm train's model.npz: the estimator on vectors, read back
        as an SPMEstimator by spm evaluate and spm predict); returns the path."""
        check_fitted(self, self.FITTED)
        return self.model_.save(path)


class SPMNeighbours(PoseEstimator):
    """KNN (Table 2) on the re-projected vectors of ``spm`` (an SPMPose, fitted
    here on the same frames unless it already is)."""

    FITTED = ("spm_", "knn_")
    NEEDS = SPMPose.NEEDS

    def __init__(self, *, k: int = 1, spm: SPMPose | None = None):
        self.k = k
        self.spm = spm

    def features_found(self, frames) -> np.ndarray:
        """(n,) bool: the frames with SPM query features (by the fitted SPM's feature configuration)."""
        check_fitted(self, self.FITTED)
        return self.spm_.features_found(frames)

    def fit(self, frames, poses) -> "SPMNeighbours":
        spm = self.spm if self.spm is not None else SPMPose()
        self.spm_ = spm if is_fitted(spm, spm.FITTED) else spm.fit(frames, poses)
        X = self.spm_.vectors(frames, "train")
        ok = np.isfinite(X).all(axis=1)
        self.knn_ = KNNPose(k=self.k).fit(self.spm_.model_.transform(X[ok]), np.asarray(poses, np.float64)[ok])
        return self

    def predict(self, frames) -> np.ndarray:
        check_fitted(self, self.FITTED)
        X = self.spm_.vectors(frames, "query")
        ok = np.isfinite(X).all(axis=1)
        out = np.full((len(X), 6), np.nan)
        if ok.any():
            out[ok] = self.knn_.predict(self.spm_.model_.transform(X[ok]))
        return out



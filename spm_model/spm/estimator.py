"""The SPM pose estimator: 16-d initial-manifold vectors -> sparse re-projection (SPP)
-> RBF regressor -> 6-DoF label; saved and loaded as one ``.npz`` file together
with the feature configuration, so ``spm predict`` can start from an image.

Scaling: Eq. 5 is solved exactly (one l1 problem per vector, over all the
others, all at once: spm_model.spm.sparse.l1_simplex) for at most ``projection_samples`` training vectors, a seeded
random
subset: the projection is a (2 gamma x d) matrix, which the subset estimates as
well as the whole set, at a cost that does not grow with n (about 1 s here).
``projection="knn"`` restricts each problem to the ``neighbours`` nearest
vectors (faster, measurably less accurate: benchmarks/train_scaling.py). The
regressor switches to ``landmarks`` Nystrom centres above that many vectors.
"""

from __future__ import annotations

from dataclasses import asdict
from pathlib import Path

import numpy as np

from spm_model.spm.features import FeatureConfig, image_features
from spm_model.errors import ModelError
from spm_model.base.estimator import Estimator, check_fitted
from spm_model.base.model_files import check_xy, load_model_file, need, need_finite, save_model_file
from spm_model.spm.regressor import RBFPoseRegressor
from spm_model.spm.sparse import SparseError, SparseProjection, fit_projection

class SPMEstimator(Estimator):
    """fit(X (n, 2 gamma), y (n, 6)) -> self; predict(X) -> (n, 6) labels.
    Learned: ``projection_`` (a SparseProjection) and ``regressor_`` (a fitted RBFPoseRegressor)."""

    FITTED = ("projection_", "regressor_")

    def __init__(self, *, projection: str = "exact", neighbours: int = 64, projection_samples: int = 1000,
                 dims: int | None = None, alpha: float = 1e-3, noise: float = 0.01, noise_copies: int = 1,
                 landmarks: int = 2000, seed: int = 0, features: FeatureConfig = FeatureConfig()):
        self.projection = projection
        self.neighbours = neighbours
        self.projection_samples = projection_samples
        self.dims = dims
        self.alpha = alpha
        self.noise = noise
        self.noise_copies = noise_copies
        self.landmarks = landmarks
        self.seed = seed
        self.features = features


    def _regressor_params(self) -> dict:
        return {"alpha": self.alpha, "noise": self.noise, "noise_copies": self.noise_copies,
                "landmarks": self.landmarks, "seed": self.seed}

    def fit(self, X, y) -> "SPMEstimator":
        X, y = check_xy(X, y, self.features.dims)
        if len(X) < 10:
            raise ModelError(f"need at least 10 training frames with features, got {len(X)}")
        rng = np.random.default_rng(self.seed)
        subset = rng.choice(len(X), min(len(X), self.projection_samples), replace=False)
        try:
            projection = fit_projection(X[subset], dims=self.dims, method=self.projection, k=self.neighbours)
        except SparseError as exc:
            raise ModelError(f"sparse re-projection failed: {exc}") from None
        regressor = RBFPoseRegressor(**self._regressor_params()).fit(projection.transform(X), y)
        self.projection_, self.regressor_ = projection, regressor
        return self


    def transform(self, X) -> np.ndarray:
        """(n, 2 gamma) manifold vectors -> (n, d) re-projected vectors."""
        check_fitted(self, self.FITTED)
        return self.projection_.transform(check_xy(X, dims=self.features.dims))

    def predict(self, X) -> np.ndarray:
        """(n, 2 gamma) -> (n, 6): rx, ry, rz in (-180, 180] degrees, t in metres."""
        check_fitted(self, self.FITTED)
        return self.regressor_.predict(self.transform(X))

    def predict_image(self, rgb, mask=None) -> dict:
        """One (H, W, 3) uint8 image (optional (H, W) mask / region of interest) ->
        {"pose": (6,), "eccentricity", "keypoints"}; FeatureError when SIFT finds too little."""
        check_fitted(self, self.FITTED)
        f = image_features(rgb, mask, self.features, raw=False)
        return {"pose": self.predict(f["vector"][None])[0], "eccentricity": f["eccentricity"],
                "keypoints": f["keypoints"]}

    # -- one-file persistence (no pickle: arrays plus a JSON header) --
    def save(self, path) -> Path:
        """The model file: parameters and the feature configuration in the header; the arrays
        W (projection), centres, dual_coef and mean (regressor); the RBF kernel coefficient
        ``kernel_coef_`` is the header's ``gamma_`` (the file format keeps its key)."""
        check_fitted(self, self.FITTED)
        params = {k: v for k, v in self.get_params().items() if k != "features"}
        reg = self.regressor_
        return save_model_file(path, "spm", params,
                               {"W": self.projection_.W, "centres": reg.X_fit_, "dual_coef": reg.dual_coef_,
                                "mean": reg.mean_},
                               {"features": asdict(self.features), "gamma_": reg.kernel_coef_})

    @classmethod
    def load(cls, path) -> "SPMEstimator":
        return cls.from_model_file(*load_model_file(path, "spm"))

    @classmethod
    def from_model_file(cls, header: dict, arrays: dict) -> "SPMEstimator":
        """The model a file's (header, arrays) describe (load_model_file); KeyError naming the
        first missing entry, in the order params, features, W, gamma_, centres, dual_coef, mean."""
        # A model saved before min_side existed computed its features without upsampling.
        params = {**header["params"], "features": FeatureConfig(**{"min_side": 1, **header["features"]})}
        projection = SparseProjection(W=arrays["W"])
        regressor = RBFPoseRegressor.from_state(
            kernel_coef_=header["gamma_"], X_fit_=arrays["centres"], dual_coef_=arrays["dual_coef"],
            mean_=arrays["mean"], **cls(**params)._regressor_params())
        return cls.from_state(projection_=projection, regressor_=regressor, **params)

    def check_loaded(self) -> None:
        """ValueError when a loaded model's arrays do not fit together (a damaged or hand-made file)."""
        check_fitted(self, self.FITTED)
        W, reg = np.asarray(self.projection_.W), self.regressor_
        need(W.ndim == 2 and W.shape[0] == self.features.dims,
              f"projection W is {W.shape}, expected ({self.features.dims}, d)")
        need(reg.X_fit_.ndim == 2 and reg.X_fit_.shape[1] == W.shape[1] and len(reg.X_fit_) > 0,
              f"centres are {reg.X_fit_.shape}, expected (m, {W.shape[1]})")
        need(reg.dual_coef_.shape == (len(reg.X_fit_), 9), f"dual_coef is {reg.dual_coef_.shape}, "
              f"expected ({len(reg.X_fit_)}, 9)")
        need(np.shape(reg.mean_) == (9,), f"mean is {np.shape(reg.mean_)}, expected (9,)")
        need(isinstance(reg.kernel_coef_, (int, float)) and reg.kernel_coef_ > 0, f"gamma_ is {reg.kernel_coef_!r}")
        need_finite(W, reg.X_fit_, reg.dual_coef_, reg.mean_)

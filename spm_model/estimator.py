"""The SPM pose estimator: 16-d initial-manifold vectors -> sparse re-projection (SPP)
-> RBF regressor -> 6-DoF label; saved and loaded as one ``.npz`` file together
with the feature configuration, so ``spm predict`` can start from an image.

Scaling: Eq. 5 is solved exactly (one linear programme per vector, over all the
others) for at most ``projection_samples`` training vectors, a seeded random
subset: the projection is a (2 gamma x d) matrix, which the subset estimates as
well as the whole set, at a cost that does not grow with n (about 14 s here).
``projection="knn"`` restricts each problem to the ``neighbours`` nearest
vectors (faster, measurably less accurate: benchmarks/train_scaling.py). The
regressor switches to ``landmarks`` Nystrom centres above that many vectors.
"""

from __future__ import annotations

import json
import zipfile
import zlib
from dataclasses import asdict
from pathlib import Path

import numpy as np

from spm_data.errors import SpmError, one_line
from spm_data.shards import write_npz_atomic
from spm_model.features import FeatureConfig, image_features
from spm_model.regressor import RBFPoseRegressor
from spm_model.sparse import SparseError, SparseProjection, fit_projection

MODEL_FORMAT = 1


class ModelError(SpmError):
    """A model cannot be trained, loaded or applied to this input."""


def check_xy(X, y=None, dims=None):
    """Validate (n, d) finite features and (n, 6) labels at the estimator boundary."""
    X = np.asarray(X, dtype=np.float64)
    if X.ndim != 2 or (dims is not None and X.shape[1] != dims):
        want = f"(n, {dims})" if dims else "(n, d)"
        raise ModelError(f"expected features of shape {want}, got {X.shape}; extract them with "
                         "spm_model.features (the same feature configuration as in training)")
    if not np.isfinite(X).all():
        raise ModelError("features contain NaN/inf; drop frames whose feature extraction failed")
    if y is None:
        return X
    y = np.asarray(y, dtype=np.float64)
    if y.shape != (len(X), 6) or not np.isfinite(y).all():
        raise ModelError(f"expected finite labels of shape ({len(X)}, 6) (rx, ry, rz degrees, t metres), "
                         f"got {y.shape}")
    return X, y


def save_model_file(path, kind: str, params: dict, arrays: dict, extra: dict | None = None) -> Path:
    """One ``.npz``: a JSON header (format, kind, parameters) and named arrays; no pickle."""
    path = Path(path)
    header = {"format": MODEL_FORMAT, "kind": kind, "params": params, **(extra or {})}
    return write_npz_atomic(path, header=np.array(json.dumps(header)), **arrays)


def _need(ok: bool, what: str) -> None:
    """A loaded model's consistency check: ValueError(what) unless ``ok``."""
    if not ok:
        raise ValueError(what)


def _need_finite(*arrays) -> None:
    _need(all(np.isfinite(np.asarray(a, dtype=np.float64)).all() for a in arrays), "arrays hold NaN or inf")


def load_model_file(path, kind: str | None = None) -> tuple[dict, dict]:
    """(header, arrays) of a model file; ModelError naming the file for a missing, truncated,
    corrupt, foreign or newer one."""
    retrain = "retrain it with spm train"
    foreign = "give the model.npz or reference-model.npz that spm train wrote, or retrain with spm train"
    magic = b""
    try:
        with open(path, "rb") as fh:
            magic = fh.read(4)
        z = np.load(path, allow_pickle=False)
    except FileNotFoundError:
        raise ModelError(f"model file not found: {path}; train one with spm train") from None
    except IsADirectoryError:
        raise ModelError(f"{path}: is a folder, not a model file; {foreign}") from None
    except PermissionError as exc:
        raise ModelError(f"{path}: cannot read the model file ({exc.strerror}); check its permissions") from None
    except (OSError, ValueError, EOFError, zipfile.BadZipFile, zlib.error) as exc:
        if not magic:
            raise ModelError(f"{path}: damaged spm model file (an empty file); {retrain}") from None
        if magic.startswith(b"PK"):  # a zip (every .npz is one) that cannot be read
            raise ModelError(f"{path}: damaged spm model file (truncated or corrupt: {type(exc).__name__}: "
                             f"{one_line(exc)}); {retrain}") from None
        raise ModelError(f"{path}: not an spm model file (not an .npz archive); {foreign}") from None
    if not isinstance(z, np.lib.npyio.NpzFile):
        raise ModelError(f"{path}: not an spm model file (a single numpy array, not an .npz archive); {foreign}")
    with z:
        if "header" not in z.files:
            raise ModelError(f"{path}: not an spm model file (an .npz archive without spm's header); {foreign}")
        try:
            header = json.loads(str(z["header"]))
            arrays = {k: z[k] for k in z.files if k != "header"}
        except (OSError, KeyError, ValueError, EOFError, zipfile.BadZipFile, zlib.error) as exc:
            raise ModelError(f"{path}: damaged spm model file (truncated or corrupt: "
                             f"{type(exc).__name__}: {one_line(exc)}); {retrain}") from None
    if not isinstance(header, dict) or not isinstance(header.get("format", 0), int):
        raise ModelError(f"{path}: damaged spm model file (its header is not spm's); {retrain}")
    if header.get("format", 0) > MODEL_FORMAT or (kind is not None and header.get("kind") != kind):
        raise ModelError(f"{path}: model format {header.get('format')} of kind {header.get('kind')} is not one "
                         f"this spm reads here ({kind or 'any'}, format {MODEL_FORMAT}); retrain or upgrade spm")
    return header, arrays


class SPMEstimator:
    """fit(X (n, 2 gamma), y (n, 6)) -> self; predict(X) -> (n, 6) labels."""

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

    def _regressor(self) -> RBFPoseRegressor:
        return RBFPoseRegressor(alpha=self.alpha, noise=self.noise, noise_copies=self.noise_copies,
                                landmarks=self.landmarks, seed=self.seed)

    def fit(self, X, y) -> "SPMEstimator":
        X, y = check_xy(X, y, self.features.dims)
        if len(X) < 10:
            raise ModelError(f"need at least 10 training frames with features, got {len(X)}")
        rng = np.random.default_rng(self.seed)
        subset = rng.choice(len(X), min(len(X), self.projection_samples), replace=False)
        try:
            self.projection_ = fit_projection(X[subset], dims=self.dims, method=self.projection,
                                              k=self.neighbours)
        except SparseError as exc:
            raise ModelError(f"sparse re-projection failed: {exc}") from None
        self.regressor_ = self._regressor().fit(self.transform(X), y)
        return self

    def transform(self, X) -> np.ndarray:
        """(n, 2 gamma) manifold vectors -> (n, d) re-projected vectors."""
        if not hasattr(self, "projection_"):
            raise ModelError("this model is not fitted yet; call fit(X, y) first")
        return self.projection_.transform(check_xy(X, dims=self.features.dims))

    def predict(self, X) -> np.ndarray:
        """(n, 2 gamma) -> (n, 6): rx, ry, rz in (-180, 180] degrees, t in metres."""
        Z = self.transform(X)  # checks that the model is fitted
        return self.regressor_.predict(Z)

    def predict_image(self, rgb, mask=None) -> dict:
        """One (H, W, 3) uint8 image (optional (H, W) mask / region of interest) ->
        {"pose": (6,), "eccentricity", "keypoints"}; FeatureError when SIFT finds too little."""
        f = image_features(rgb, mask, self.features, raw=False)
        return {"pose": self.predict(f["vector"][None])[0], "eccentricity": f["eccentricity"],
                "keypoints": f["keypoints"]}

    # -- one-file persistence (no pickle: arrays plus a JSON header) --
    def save(self, path) -> Path:
        if not hasattr(self, "regressor_"):
            raise ModelError("fit the model before saving it")
        params = {k: v for k, v in vars(self).items() if not k.endswith("_") and k != "features"}
        return save_model_file(path, "spm", params,
                               {"W": self.projection_.W, "centres": self.regressor_.X_fit_,
                                "dual_coef": self.regressor_.dual_coef_, "mean": self.regressor_.mean_},
                               {"features": asdict(self.features), "gamma_": self.regressor_.gamma_})

    @classmethod
    def load(cls, path) -> "SPMEstimator":
        return cls.from_model_file(*load_model_file(path, "spm"))

    @classmethod
    def from_model_file(cls, header: dict, arrays: dict) -> "SPMEstimator":
        """The model a file's (header, arrays) describe (load_model_file)."""
        model = cls(**header["params"], features=FeatureConfig(**header["features"]))
        model.projection_ = SparseProjection(W=arrays["W"])
        reg = model._regressor()
        reg.gamma_, reg.X_fit_, reg.dual_coef_, reg.mean_ = (header["gamma_"], arrays["centres"],
                                                              arrays["dual_coef"], arrays["mean"])
        model.regressor_ = reg
        return model

    def check_loaded(self) -> None:
        """ValueError when a loaded model's arrays do not fit together (a damaged or hand-made file)."""
        W, reg = np.asarray(self.projection_.W), self.regressor_
        _need(W.ndim == 2 and W.shape[0] == self.features.dims,
              f"projection W is {W.shape}, expected ({self.features.dims}, d)")
        _need(reg.X_fit_.ndim == 2 and reg.X_fit_.shape[1] == W.shape[1] and len(reg.X_fit_) > 0,
              f"centres are {reg.X_fit_.shape}, expected (m, {W.shape[1]})")
        _need(reg.dual_coef_.shape == (len(reg.X_fit_), 9), f"dual_coef is {reg.dual_coef_.shape}, "
              f"expected ({len(reg.X_fit_)}, 9)")
        _need(np.shape(reg.mean_) == (9,), f"mean is {np.shape(reg.mean_)}, expected (9,)")
        _need(isinstance(reg.gamma_, (int, float)) and reg.gamma_ > 0, f"gamma_ is {reg.gamma_!r}")
        _need_finite(W, reg.X_fit_, reg.dual_coef_, reg.mean_)

"""Every method the benchmark runs, behind one interface (scikit-learn's):
``fit(frames, poses)`` returns self, ``predict(frames)`` returns (n, 6) labels
(rx, ry, rz degrees, t metres; a row of NaN where the method has no estimate).
``frames`` is a sequence of per-frame dicts (spm_model/frames.py); poses (n, 6).
Learned state ends in ``_`` (each class's ``FITTED``); predict before fit raises
ModelError (spm_model/fitted.py).

Built in: SPM and KNN on its re-projected vectors (the paper's Tables 1 and 2),
the PCA- and LS-based raw-image baselines (§3.3-3.4), the reference template
matcher (spm_model/template.py) and chance (a random training pose). Any class
with the same contract joins them: ``spm train --estimator MODULE:CLASS``
(docs/estimators.md).
"""

from __future__ import annotations

import importlib
import re

import numpy as np

from spm_model.baselines import KNNPose, LSPose, PCAPose
from spm_model.estimator import SPMEstimator
from spm_model.features import FeatureConfig, FeatureError, image_features, raw_vector
from spm_model.fitted import ModelError, check_fitted, is_fitted
from spm_model.frames import column
from spm_model.template import TemplatePose

METHOD_NAMES = {"spm": "SPM", "knn1": "KNN K=1", "knn3": "KNN K=3", "pca": "PCA-based", "ls": "LS-based",
                "template": "HOG templates (reference)", "chance": "chance (random training pose)"}
MIN_TRAIN_FRAMES = 10


def _spm_vector(frame, config: FeatureConfig) -> np.ndarray:
    try:
        return image_features(frame["rgb"], frame["mask"], config, raw=False)["vector"]
    except FeatureError:
        return np.full(config.dims, np.nan)


class SPMPose:
    """SPM (spm_model/estimator.py) on frames: training frames use their cached
    ``train_vector`` (the path-neighbour keypoint rule) when the sequence has
    it, test frames their ``query_vector``; without a cache, features are
    computed from each image by the query rule. Frames without a feature are
    left out of training and get NaN."""

    FITTED = ("model_",)

    def __init__(self, *, seed: int = 0, features: FeatureConfig = FeatureConfig(), params: dict | None = None):
        self.seed = seed
        self.features = features
        self.params = params

    def vectors(self, frames, kind: str) -> np.ndarray:
        return column(frames, f"{kind}_vector", lambda f: _spm_vector(f, self.features))

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


class SPMNeighbours:
    """KNN (Table 2) on the re-projected vectors of ``spm`` (an SPMPose, fitted
    here on the same frames unless it already is)."""

    FITTED = ("spm_", "knn_")

    def __init__(self, *, k: int = 1, spm: SPMPose | None = None):
        self.k = k
        self.spm = spm

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


class RawImagePose:
    """The paper's appearance baselines on 32 x 32 grey object boxes:
    ``kind = "pca"`` (PCA + nearest neighbour) or ``"ls"`` (least squares)."""

    FITTED = ("model_",)

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


class ChancePose:
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


def builtin_methods(seed: int, features: FeatureConfig, model_params: dict | None = None) -> dict:
    """Fresh, unfitted instances of every built-in method, in report order."""
    spm = SPMPose(seed=seed, features=features, params=model_params)
    return {"spm": spm, "knn1": SPMNeighbours(k=1, spm=spm), "knn3": SPMNeighbours(k=3, spm=spm),
            "pca": RawImagePose(kind="pca"), "ls": RawImagePose(kind="ls"), "template": TemplatePose(),
            "chance": ChancePose(seed=seed)}


def load_estimator_class(spec: str):
    """'MODULE:CLASS' (MODULE importable, e.g. on PYTHONPATH) -> the class; ModelError otherwise."""
    match = re.fullmatch(r"([A-Za-z_][\w.]*):([A-Za-z_]\w*)", spec or "")
    if not match:
        raise ModelError(f"--estimator expects MODULE:CLASS (for example my_pose:MyEstimator), got {spec!r}")
    try:
        module = importlib.import_module(match.group(1))
    except Exception as exc:  # noqa: BLE001 - a user's module can fail in any way; report it in one line
        raise ModelError(f"--estimator {spec}: cannot import {match.group(1)} ({type(exc).__name__}: {exc}); "
                         "is its folder on PYTHONPATH?") from None
    cls = getattr(module, match.group(2), None)
    if cls is None or not all(callable(getattr(cls, m, None)) for m in ("fit", "predict")):
        raise ModelError(f"--estimator {spec}: {match.group(2)} is not a class in {match.group(1)} with "
                         "fit(frames, poses) and predict(frames)")
    return cls


def check_predictions(name: str, pred, n: int) -> np.ndarray:
    """A method's predict() output as (n, 6) float64; ModelError naming the method otherwise."""
    try:
        out = np.asarray(pred, dtype=np.float64)
    except (TypeError, ValueError):
        out = None
    if out is None or out.shape != (n, 6):
        got = "something that is not an array" if out is None else f"shape {out.shape}"
        raise ModelError(f"estimator {name}: predict(frames) must return ({n}, 6) labels "
                         f"(rx, ry, rz degrees, t metres; NaN rows for no estimate), got {got}")
    return out

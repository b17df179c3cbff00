"""spm_model: the Sparse Pose Manifolds method (Kouskouridas et al. 2014) and the benchmark.

The public face, for a notebook (docs/architecture.md, "From a notebook"): ``train`` (the
benchmark and its report), ``evaluate_model``, ``load_model``, ``predict_images``, the
estimators on frames (``SPMPose``, ``RawImagePose``, ``TemplatePose``, ``ChancePose``, each
``fit(frames, poses)`` / ``predict(frames)``; ``builtin_methods`` builds every built-in one),
``PoseEstimator`` and the errors. Each is imported on first use.

Layers, lowest first (each imports its own and those below, never above): ``errors``,
``base`` (the PoseEstimator contract and its one fitted check, the frames methods
get, model files), ``spm`` (the method's stages: keypoints, bunches, ellipse,
manifold, sparse, regressor, features, and SPMEstimator), ``methods`` (every
benchmark method behind ``fit(frames, poses)``/``predict(frames)``: SPM, KNN,
PCA, LS, the reference templates, N3M, SIFT + PnP, SMM, chance; the registry), ``bench``
(feature cache, protocols, metrics, surface metrics, report) and ``pipelines``
(what ``spm train``, ``evaluate`` and ``predict`` call). Decisions: docs/method.md.
"""

import importlib

# name -> the module it lives in, imported on first use (PEP 562).
PUBLIC = {"train": "spm_model.pipelines.train", "evaluate_model": "spm_model.pipelines.evaluate",
          "load_model": "spm_model.pipelines.evaluate", "predict_images": "spm_model.pipelines.predict",
          "SPMPose": "spm_model.methods.spm_pose", "RawImagePose": "spm_model.methods.baselines",
          "ChancePose": "spm_model.methods.baselines", "TemplatePose": "spm_model.methods.template",
          "builtin_methods": "spm_model.methods.registry",
          "PoseEstimator": "spm_model.base.estimator", "ModelError": "spm_model.errors",
          "FeatureError": "spm_model.errors"}


def __getattr__(name):
    if name not in PUBLIC:
        raise AttributeError(f"module 'spm_model' has no attribute {name!r}")
    value = getattr(importlib.import_module(PUBLIC[name]), name)
    globals()[name] = value
    return value


__all__ = list(PUBLIC)

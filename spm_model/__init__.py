"""spm_model: the Sparse Pose Manifolds method (Kouskouridas et al. 2014) and the benchmark.

Layers, lowest first (each imports its own and those below, never above):
``base`` (the PoseEstimator contract and its one fitted check, the frames methods
get, model files), ``spm`` (the method's stages: keypoints, bunches, ellipse,
manifold, sparse, regressor, features, and SPMEstimator), ``methods`` (every
benchmark method behind ``fit(frames, poses)``/``predict(frames)``: SPM, KNN,
PCA, LS, the reference templates, N3M, SIFT + PnP, SMM, chance; the registry), ``bench``
(feature cache, protocols, metrics, surface metrics, report) and ``commands``
(what ``spm train``, ``evaluate`` and ``predict`` call). Decisions: docs/method.md.
"""

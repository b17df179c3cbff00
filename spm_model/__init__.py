"""spm_model: the Sparse Pose Manifolds estimator (Kouskouridas et al. 2014).

The paper's stages, one module each: ``keypoints`` (SIFT + homography RANSAC
against the path neighbours), ``bunches`` (EM, gamma = 8), ``ellipse`` (Eq. 1 by
particle swarm, and the direct fit), ``manifold`` (foci distances in a canonical
order), ``sparse`` (Eq. 5 as Sparsity Preserving Projections) and ``regressor``
(RBF kernel ridge with input noise, angles as cos/sin). Around them:
``features`` and ``dataset`` (per-frame features, cached per shard),
``estimator`` (the model and its file), ``baselines``, ``metrics``,
``evaluation`` (protocols), ``report`` and ``train`` (what ``spm`` calls).
Decisions: docs/method.md.
"""

"""spm_model: the Sparse Pose Manifolds estimator (Kouskouridas et al. 2014).

Present so far (docs/method.md): ``keypoints`` (SIFT + homography RANSAC against
the path neighbour), ``bunches`` (EM, gamma = 8), ``ellipse`` (Eq. 1 by particle
swarm, and the direct fit), ``manifold`` (foci distances in a canonical order)
``sparse`` (Eq. 5 as Sparsity Preserving Projections) and ``regressor`` (RBF
kernel ridge trained with input noise, angles as cos/sin). Feature caching,
`spm train`, the baselines and the reports arrive with their issue.
"""

"""spm_model: the Sparse Pose Manifolds estimator (Kouskouridas et al. 2014).

Present so far (docs/method.md): ``keypoints`` (SIFT + homography RANSAC against
the path neighbour), ``bunches`` (EM, gamma = 8), ``ellipse`` (Eq. 1 by particle
swarm, and the direct fit), ``manifold`` (foci distances in a canonical order)
and ``sparse`` (Eq. 5 as Sparsity Preserving Projections). The regressor,
`spm train` and the reports arrive with their issue.
"""

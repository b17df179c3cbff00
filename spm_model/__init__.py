"""spm_model: the Sparse Pose Manifolds estimator (Kouskouridas et al. 2014).

Present so far (docs/method.md): ``keypoints`` (SIFT + homography RANSAC against
the path neighbour), ``bunches`` (EM, gamma = 8), ``ellipse`` (Eq. 1 by particle
swarm, and the direct fit) and ``manifold`` (foci distances in a canonical order).
The sparse re-projection, the regressor, `spm train` and the reports arrive with
their issue.
"""

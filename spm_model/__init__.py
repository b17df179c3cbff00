"""spm_model: the Sparse Pose Manifolds estimator (Kouskouridas et al. 2014).

Present so far: ``ellipse`` (Eq. 1's regularised conic fit by particle swarm,
and the direct fit) and ``manifold`` (the foci-distance vector in a canonical
order). Keypoints, the EM bunches, the sparse re-projection, the regressor,
`spm train` and the reports arrive with their issue.
"""

"""spm_model: the Sparse Pose Manifolds estimator (Kouskouridas et al. 2014).

Not built yet: the estimator, `spm train` and the reports arrive with their own
issue. This package exists so the layout and the `spm` command are in place.
"""

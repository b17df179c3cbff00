"""The SPM method's stages (keypoints, bunches, ellipse, manifold, sparse re-projection, regressor), its per-frame
features and SPMEstimator."""

"""Every method the benchmark runs, behind fit(frames, poses) / predict(frames): SPM and KNN on
its vectors, PCA, LS, the reference HOG templates, N3M, SIFT + PnP, SMM, chance; registry.py lists
them."""

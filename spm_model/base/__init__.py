"""The bottom of spm_model: the estimator contract (``estimator``), the frames every
method gets (``frames``) and model files (``model_files``)."""

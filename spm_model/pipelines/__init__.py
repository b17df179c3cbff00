"""The work of spm train, evaluate, predict and check-estimator: the pipelines the command line
(spm_cli/model.py) calls, one library function each."""

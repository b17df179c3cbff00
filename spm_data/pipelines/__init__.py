"""The work of each spm-data command (render, occlude, merge, info, validate, show and hist): the pipelines
the command line (spm_cli/data.py) calls, one library function each."""

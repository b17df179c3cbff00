"""Tests mirror the library: spm_data/<layer>/<module>.py is tested in tests/<layer>/test_<module>.py,
spm_model/ in tests/model/, spm_cli/ in tests/cli/, cli.py in tests/test_cli.py; what spans many modules
is in tests/system/ (tests/system/test_layout.py keeps it so)."""

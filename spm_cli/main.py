"""The two command-line programs: ``spm-data`` (make, import, check and export labelled 6-DoF pose
datasets) and ``spm`` (train, evaluate and apply pose estimators on them).

Their commands are spm_cli/data.py, importers.py and model.py, one library call each; what they
share (one-line errors, progress, the executor options, old spellings) is spm_cli/support.py.
spm_cli is the only package that imports click. One grammar throughout: the input is the first
argument, every output is ``--out`` (README.md, "Command line").
"""

import os
import sys

# Before anything else is imported: a Ctrl-C or SIGTERM from the first instant is one line and
# 130 / 143 (spm_data/jobs/outcome.py). Only as the installed programs: a process that imports
# this module (tests, notebooks) keeps its own handlers.
from spm_data.jobs.outcome import catch_signals_early

# Not in a worker process that multiprocessing spawned: it runs this module again (as part of the
# program's main script) with the parent's sys.argv, and its signals are the parent's to handle.
if os.path.basename(sys.argv[0]) in ("spm", "spm-data") and "--multiprocessing-fork" not in sys.orig_argv:
    catch_signals_early()

import click  # noqa: E402 - after the signal handlers, on purpose

from spm_cli.data import (export_group, hist_cmd, info_cmd, merge_cmd, occlude_cmd, render_cmd,  # noqa: E402
                          show_cmd, validate_cmd)
from spm_cli.importers import import_group  # noqa: E402
from spm_cli.model import check_estimator_cmd, evaluate_cmd, predict_cmd, train_cmd  # noqa: E402
from spm_cli.support import Group  # noqa: E402


@click.group(cls=Group)
@click.version_option(package_name="spm")
def data_cli():
    """spm-data: make labelled 6-DoF pose datasets (HDF5 shards)."""


for command in (render_cmd, occlude_cmd, import_group, merge_cmd, export_group, validate_cmd, info_cmd, show_cmd,
                hist_cmd):
    data_cli.add_command(command)


@click.group(cls=Group)
@click.version_option(package_name="spm")
def model_cli():
    """spm: train and evaluate the Sparse Pose Manifolds estimator on spm-data shards."""


for command in (train_cmd, evaluate_cmd, predict_cmd, check_estimator_cmd):
    model_cli.add_command(command)

__all__ = ["data_cli", "model_cli"]

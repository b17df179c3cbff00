"""The two command-line programs: ``spm-data`` (make, import, check and export labelled 6-DoF pose
datasets) and ``spm`` (train, evaluate and apply pose estimators on them).

The commands live with the layer they drive (spm_data/commands/cli_data.py and cli_import.py,
spm_model/commands/cli_model.py); what they share (one-line errors, progress, the executor
options, old spellings) is spm_data/commands/cli_support.py. One grammar throughout: the input
is the first argument, every output is ``--out`` (README.md, "Command line").
"""

import click

from spm_data.commands.cli_data import (export_group, hist_cmd, info_cmd, merge_cmd, occlude_cmd, render_cmd,
                                        show_cmd, validate_cmd)
from spm_data.commands.cli_import import import_group
from spm_data.commands.cli_support import Group
from spm_model.commands.cli_model import check_estimator_cmd, evaluate_cmd, predict_cmd, train_cmd


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

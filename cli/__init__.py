"""Command-line interface: ``spm-data`` (datasets, cli/data.py) and ``spm`` (the model,
cli/model.py).

Each command is a thin wrapper around one library call; library errors
(SpmError) are printed as one line and exit with status 1.
"""

from cli.data import data_cli
from cli.model import model_cli

__all__ = ["data_cli", "model_cli"]

"""The entry of the two programs, ``spm-data`` and ``spm`` (pyproject.toml's console scripts):
their groups and commands are spm_cli/ (spm_cli/main.py), the only package that imports click."""

from spm_cli.main import data_cli, model_cli

__all__ = ["data_cli", "model_cli"]

"""``spm-data import``: real datasets into shards (cli.py adds the group to spm-data), one command
per entry of spm_data.formats.IMPORTERS, built here from its options. The dataset is the first
argument, the shards go to --out."""

from __future__ import annotations

import importlib

import click

from spm_cli.support import Group, executor_options, handle_errors, old_spelling, run_with_progress
from spm_data.formats import IMPORTERS, Option

import_group = Group("import", help="Turn real datasets (COIL-100, COIL-20, CVL, BOP, transforms.json captures, "
                                    "any posed-image folder) into shards.")

OUT = click.option("--out", default="out_imported", show_default=True, type=click.Path(),
                   help="Folder to write the shards to.")


def _click_type(option: Option):
    if isinstance(option.kind, tuple):
        return click.Choice(list(option.kind))
    if option.kind in ("int", "float") and (option.low is not None or option.high is not None):
        ranged = click.IntRange if option.kind == "int" else click.FloatRange
        return ranged(option.low, option.high)
    return {"int": int, "float": float, "str": str, "path": click.Path()}[option.kind]


def _click_option(option: Option):
    if option.kind == "flag":
        return click.option(option.flag, option.name, is_flag=True, default=bool(option.default), help=option.help)
    return click.option(option.flag, option.name, type=_click_type(option), default=option.default,
                        show_default=option.default is not None, help=option.help)


def _finish_import(call):
    from spm_data.formats.importing import import_report

    problems = []

    def run(bar):
        summary, found = call(bar)
        problems.extend(found)
        return summary

    run_with_progress(run, lambda summary: import_report(summary, problems))


def _command(name: str, importer):
    def command(path, out, executor, **options):
        function = getattr(importlib.import_module(importer.module), importer.function)
        _finish_import(lambda bar: function(path, out, progress=bar, executor=executor, **options))

    command.__doc__ = importer.help
    command = handle_errors(command)
    for flag, dest, advice in importer.old:
        command = old_spelling(flag, dest, advice, type=click.Path())(command)
    command = executor_options("Import processes")(command)
    for option in reversed(importer.options):
        command = _click_option(option)(command)
    command = OUT(command)
    command = click.argument("path", type=click.Path())(command)
    return click.command(name, help=importer.help)(command)


for _name, _importer in IMPORTERS.items():
    import_group.add_command(_command(_name, _importer))

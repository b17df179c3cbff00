"""spm_data.formats: the importer registry, one entry per `spm-data import` command, each option a
keyword of the importer's function."""

import importlib
import inspect

from click.testing import CliRunner

from cli import data_cli
from spm_cli.importers import import_group
from spm_data.formats import IMPORTERS, Importer, Option, importer_names


def test_one_command_per_registered_importer_with_exactly_its_options():
    assert list(import_group.commands) == list(importer_names()) == ["coil100", "coil20", "folder", "cvl", "bop",
                                                                     "nerf"]
    for name, importer in IMPORTERS.items():
        function = getattr(importlib.import_module(importer.module), importer.function)
        keywords = inspect.signature(function).parameters
        assert all(o.name in keywords for o in importer.options), name
        assert {"progress", "executor"} <= set(keywords), name
        command = import_group.commands[name]
        shown = {p.opts[0] for p in command.params if getattr(p, "opts", None) and not getattr(p, "hidden", False)}
        assert {o.flag for o in importer.options} <= shown, name
        assert command.help == importer.help


def test_a_new_entry_is_a_new_command(monkeypatch, tmp_path):
    """Adding an importer touches the one table: the command, its options and its help follow."""
    import spm_cli.importers as cli_import

    module = tmp_path / "toy_format.py"
    module.write_text("def import_toy(path, out_dir, *, answer=1, progress=None, executor=None):\n"
                      "    raise __import__('spm_data.errors').errors.SpmError(f'toy {path} {answer}')\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    command = cli_import._command("toy", Importer("toy_format", "import_toy", "Toys at PATH.",
                                                  (Option("--answer", "answer", "int", 1, "The answer.", 0, 99),)))
    monkeypatch.setitem(import_group.commands, "toy", command)
    r = CliRunner().invoke(data_cli, ["import", "toy", "here", "--answer", "42"])
    assert (r.exit_code, r.output) == (1, "error: toy here 42\n")
    r = CliRunner().invoke(data_cli, ["import", "toy", "here", "--answer", "420"])
    assert r.exit_code == 2 and "420 is not in the range 0<=x<=99" in r.output

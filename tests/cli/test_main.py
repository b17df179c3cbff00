"""cli.py: the two programs and their one grammar: every command listed with its whole summary,
every option with help, the input as the first argument, ``--out`` for every output, the
executor options on every command that runs jobs, and the old spellings still accepted for
one release with a one-line notice."""

import click
import pytest
from click.testing import CliRunner

from cli import data_cli, model_cli

EXECUTOR = {"--workers", "--recycle-after", "--executor", "--address", "--task-cpus"}
RUNS_JOBS = {"render", "occlude", "merge", "import coil100", "import coil20", "import folder", "import cvl",
             "import bop", "import nerf", "train", "evaluate"}


def commands(group, prefix=""):
    """(name, command) of every leaf command under ``group``."""
    for name, cmd in sorted(group.commands.items()):
        if isinstance(cmd, click.Group):
            yield from commands(cmd, f"{prefix}{name} ")
        else:
            yield f"{prefix}{name}", cmd


ALL = [*commands(data_cli), *commands(model_cli)]


def flags(cmd, hidden=False):
    return {o for p in cmd.params if isinstance(p, click.Option) and p.hidden == hidden for o in p.opts}


def test_the_programs_list_every_command_with_its_whole_summary():
    for group in (data_cli, model_cli, data_cli.commands["import"], data_cli.commands["export"]):
        listing = CliRunner().invoke(group, ["--help"]).output.split("Commands:")[1]
        for name, cmd in group.commands.items():
            summary = " ".join(cmd.help.split("\n\n")[0].split())
            assert summary in " ".join(listing.split()), name


@pytest.mark.parametrize("name, cmd", ALL, ids=[n for n, _ in ALL])
def test_every_option_has_help_and_outputs_are_out(name, cmd):
    shown = [p for p in cmd.params if isinstance(p, click.Option) and not p.hidden]
    assert [p.name for p in shown if not p.help] == []
    assert (EXECUTOR <= flags(cmd)) == (name in RUNS_JOBS)
    assert not {"--in", "--shards", "--report", "--classes", "--input", "--output"} & flags(cmd)
    task_cpus = [p.help for p in cmd.params if "--task-cpus" in p.opts]
    assert [h for h in task_cpus if "Blender" in h] == (task_cpus if name == "render" else [])


def test_every_command_takes_its_input_first():
    takes_input = {n: [p.human_readable_name for p in c.params if isinstance(p, click.Argument)] for n, c in ALL}
    assert takes_input == {
        "check-estimator": ["MODULE:CLASS"], "evaluate": ["SHARDS"], "export bop": ["FOLDER"], "hist": ["FOLDER"],
        "import bop": ["PATH"], "import coil100": ["PATH"], "import coil20": ["PATH"], "import cvl": ["PATH"],
        "import folder": ["PATH"], "import nerf": ["PATH"], "info": ["SHARD_OR_FOLDER"],
        "merge": ["FOLDER..."], "occlude": ["FOLDER"], "predict": ["IMAGE..."], "render": [], "show": ["SHARD"],
        "train": ["SHARDS"], "validate": ["FOLDER"]}


@pytest.mark.parametrize("group, args, notice, error", [
    (data_cli, ["occlude", "--in", "{d}"], "--in is deprecated; give the folder as the first argument", "{d}"),
    (data_cli, ["merge", "{d}", "--out", "{o}", "--classes", "cup"], "--classes is deprecated; use --rename OLD=NEW",
     "--rename: expected OLD=NEW[,OLD=NEW...], got 'cup'"),
    (model_cli, ["train", "--shards", "{d}"], "--shards is deprecated; give the folder as the first argument", "{d}"),
    (model_cli, ["train", "{o}", "--report", "{d}"], "--report is deprecated; use --out", "{o}"),
    (model_cli, ["evaluate", "--shards", "{d}", "--model", "{o}/m.npz"],
     "--shards is deprecated; give the folder as the first argument", "model file not found: {o}/m.npz"),
    (data_cli, ["import", "coil100", "{d}", "--classes", "{o}/c.csv"], "--classes is deprecated; use --class-map FILE",
     "cannot read class map {o}/c.csv"),
])
def test_old_spellings_still_reach_the_command_with_one_notice(group, args, notice, error, tmp_path):
    """Each old spelling gets its notice, then the command runs with its value: it fails on what it
    was given (an empty folder, a bad rename, a missing file), the error naming it."""
    (tmp_path / "d").mkdir()
    where = {"d": tmp_path / "d", "o": tmp_path / "o"}
    r = CliRunner().invoke(group, [a.format(**where) for a in args])
    lines = r.stderr.splitlines()
    assert lines[0] == f"warning: {notice}" and r.exit_code == 1, r.output
    assert lines[-1].startswith("error: ") and error.format(**where) in lines[-1], lines


def test_the_ignored_threshold_is_gone_from_bop(tmp_path):
    r = CliRunner().invoke(data_cli, ["import", "bop", str(tmp_path), "--threshold", "5"])
    assert r.exit_code == 2 and "No such option '--threshold'" in r.stderr
    assert "--threshold" in flags(data_cli.commands["import"].commands["coil100"])


def test_one_list_grammar_the_comma_lists_are_repeatable_too():
    lists = [(name, p) for name, cmd in ALL for p in cmd.params if {"--methods", "--sources", "--rename"} & set(p.opts)]
    assert sorted((name, p.opts[0]) for name, p in lists) == [("merge", "--rename"), ("merge", "--sources"),
                                                             ("train", "--methods")]
    assert [p.opts[0] for _, p in lists if not p.multiple] == []
    assert [p.opts[0] for _, p in lists if "several as" not in p.help and "comma-separated" not in p.help] == []

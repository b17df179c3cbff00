"""spm_cli.support: what the commands of both programs share: one-line errors (exit 1)
and warnings, the summary and exit status of a run, progress labelled with the command (its lines:
tests/jobs/test_progress.py), the executor options, old spellings with a one-line notice, and groups
that list whole command summaries."""

import re
import time
import warnings

import click
import pytest
from click.testing import CliRunner

from spm_cli.support import (Group, Progress, comma_list, executor_options, handle_errors, old_spelling,
                             run_with_progress)
from spm_data.errors import Option, ShardError, SpmError, SpmWarning


@click.command()
@click.option("--fail", default="")
@handle_errors
def command(fail):
    warnings.warn("half the shards are missing; skipped", SpmWarning)
    if fail == "spm":
        raise ShardError("cup-00000.h5: field 'K' fails its checksum; the shard is corrupt")
    if fail == "option":   # the library names occlude's options by key; the face by flag (FLAGS)
        raise SpmError(Option("min"), " 0.7 is above ", Option("max"), " 0.6; ", Option("copy"), " 1")
    if fail == "bug":
        raise ValueError("a bug")
    if fail == "signal-then-bug":   # SIGTERM's KeyboardInterrupt swallowed mid-import; the library then fails
        from spm_data.jobs import outcome
        outcome._received[0] = 15
        raise TypeError("'NoneType' object is not callable")
    click.echo("done")


def test_an_spm_error_is_one_error_line_and_exit_1():
    r = CliRunner().invoke(command, ["--fail", "spm"])
    assert r.exit_code == 1 and r.stdout == ""
    assert r.stderr == ("warning: half the shards are missing; skipped\n"
                        "error: cup-00000.h5: field 'K' fails its checksum; the shard is corrupt\n")


def test_an_error_naming_options_by_key_names_their_flags():
    r = CliRunner().invoke(command, ["--fail", "option"])
    assert r.exit_code == 1 and r.stderr.splitlines()[-1] == "error: --min 0.7 is above --max 0.6; copy 1"


def test_success_warns_in_one_line_and_exits_0():
    r = CliRunner().invoke(command, [])
    assert r.exit_code == 0 and r.stdout == "done\n"
    assert r.stderr == "warning: half the shards are missing; skipped\n"


def test_other_exceptions_are_bugs_and_propagate():
    r = CliRunner().invoke(command, ["--fail", "bug"])
    assert r.exit_code == 1 and isinstance(r.exception, ValueError) and "error:" not in r.stderr


def test_an_error_raised_after_a_signal_is_the_interruption_in_one_line():
    r = CliRunner().invoke(command, ["--fail", "signal-then-bug"])
    assert r.exit_code == 143 and r.stderr.splitlines()[-1].startswith("interrupted (SIGTERM)"), r.stderr
    assert not isinstance(r.exception, TypeError) and "Traceback" not in r.stderr


def test_other_warnings_go_to_pythons_own_display(monkeypatch):
    import spm_cli.support as support

    shown = []
    monkeypatch.setattr(support, "_python_showwarning", lambda message, category, *rest: shown.append(
        (str(message), category)))

    @click.command()
    @handle_errors
    def deprecated():
        warnings.warn("old option", DeprecationWarning)
        warnings.warn("a gap", SpmWarning)

    with warnings.catch_warnings():
        warnings.simplefilter("always")
        r = CliRunner().invoke(deprecated, [])
    assert r.exit_code == 0 and r.stderr == "warning: a gap\n"
    assert shown == [("old option", DeprecationWarning)]


class Summary:
    def __init__(self, interrupted=False, failed=()):
        self.interrupted, self.failed = interrupted, list(failed)

    def report(self):
        return f"rendered, interrupted={self.interrupted}, failed={len(self.failed)}"


@pytest.mark.parametrize("summary, code", [(Summary(), 0), (Summary(failed=["a.h5"]), 1),
                                           (Summary(interrupted=True), 130)])
def test_run_with_progress_prints_the_summary_and_exits_by_it(summary, code):
    fed = []

    @click.command()
    @handle_errors
    def run():
        def call(bar):
            bar.total = 3
            bar(2)
            bar(1)
            fed.append(bar.total)
            return summary

        run_with_progress(call)

    r = CliRunner().invoke(run, [])
    assert r.exit_code == code and r.stdout == summary.report() + "\n" and fed == [3]


def test_executor_options_become_one_executor():
    seen = []

    @click.command()
    @executor_options("Things", recycle_after=5, task_cpus="Blender wants more.")
    def run(executor):
        seen.append(executor)

    assert CliRunner().invoke(run, []).exit_code == 0
    local = seen.pop()
    assert (local.name, local.workers, local.recycle_after) == ("local", 1, 5)
    assert CliRunner().invoke(run, ["--workers", "3", "--recycle-after", "2"]).exit_code == 0
    local = seen.pop()
    assert (local.name, local.workers, local.recycle_after) == ("local", 3, 2)
    assert CliRunner().invoke(run, ["--executor", "ray", "--address", "auto", "--task-cpus", "2"]).exit_code == 0
    ray = seen.pop()
    assert (type(ray).__name__, ray.address, ray.task_cpus, ray.workers) == ("RayExecutor", "auto", 2.0, 1)
    r = CliRunner().invoke(run, ["--executor", "slurm"])
    assert r.exit_code == 2 and "'slurm' is not one of 'local', 'ray'" in r.output
    text = " ".join(CliRunner().invoke(run, ["--help"]).output.split())
    assert "--workers INTEGER RANGE Things running at once" in text and "Blender wants more." in text
    assert "[default: 5;" in text


@click.command()
@click.argument("folder", required=False)
@click.option("--out", default=None)
@old_spelling("--in", "folder", "give the folder as the first argument", required="FOLDER")
@old_spelling("--report", "out", "use --out")
@handle_errors
def renamed(folder, out):
    click.echo(f"{folder} -> {out}")


@pytest.mark.parametrize("args, stdout, stderr", [
    (["a", "--out", "b"], "a -> b\n", ""),
    (["--in", "a", "--report", "b"], "a -> b\n", "warning: --in is deprecated; give the folder as the first argument\n"
                                                 "warning: --report is deprecated; use --out\n"),
    (["a"], "a -> None\n", ""),
])
def test_old_spellings_work_with_a_one_line_notice(args, stdout, stderr):
    r = CliRunner().invoke(renamed, args)
    assert (r.exit_code, r.stdout, r.stderr) == (0, stdout, stderr)


def test_old_spellings_are_hidden_and_do_not_replace_a_missing_or_doubled_argument():
    r = CliRunner().invoke(renamed, ["--out", "b"])
    assert r.exit_code == 2 and "Missing argument 'FOLDER'." in r.stderr
    r = CliRunner().invoke(renamed, ["a", "--in", "c"])
    assert r.exit_code == 2 and "--in and its new spelling were both given" in r.stderr
    assert "--in" not in CliRunner().invoke(renamed, ["--help"]).output


def test_a_group_lists_whole_summaries():
    group = Group("g")

    @group.command("long-name")
    def long_name():
        """A summary far longer than the forty-five characters click keeps, ending with a word: sentinel.

        Details that stay out of the listing."""

    listing = " ".join(CliRunner().invoke(group, ["--help"]).output.split("Commands:")[1].split())
    assert listing == ("long-name A summary far longer than the forty-five characters click keeps, ending with a "
                       "word: sentinel.")


def wait_for(condition, timeout=30.0):
    """Poll ``condition`` until it holds (a state, not a fixed sleep); fail after ``timeout`` s."""
    deadline = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < deadline, "timed out waiting"
        time.sleep(0.005)


def test_a_command_off_a_terminal_prints_progress_lines_to_stderr_not_stdout(monkeypatch):
    """The label is the command's name; the run lasts until the first line has appeared."""
    monkeypatch.setenv("SPM_PROGRESS_EVERY", "0.02")

    @click.group()
    def program():
        pass

    @program.command("render")
    @handle_errors
    def render():
        def call(progress):
            progress.total = 100
            progress(40)
            progress.started = progress.counted - 30   # as if fed over 30 s
            wait_for(lambda: getattr(progress, "line_count", 0) >= 1)
            return Summary()

        run_with_progress(call)

    lines = []
    monkeypatch.setattr(Progress, "line", _counting(Progress.line, lines))
    r = CliRunner().invoke(program, ["render"])
    assert r.exit_code == 0 and r.stdout == Summary().report() + "\n", r.output
    printed = r.stderr.splitlines()
    assert printed and all(re.match(r"^render: 40/100 frames, [\d,.]+ frames/s, \d+ s left$", p) for p in printed)


def _counting(line, lines):
    def counted(self):
        text = line(self)
        lines.append(text)
        self.line_count = len(lines)
        return text

    return counted


def test_a_list_option_is_repeated_and_each_value_may_be_a_comma_list():
    assert comma_list(("a,b", " c ", "d,,")) == ["a", "b", "c", "d"]
    assert comma_list(()) == [] and comma_list(("",)) == []

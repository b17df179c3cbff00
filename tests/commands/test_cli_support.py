"""spm_data.commands.cli_support: what the commands of both programs share: one-line errors (exit 1)
and warnings, the summary and exit status of a run, progress (a bar on a terminal, a line every
$SPM_PROGRESS_EVERY seconds elsewhere), the executor options, old spellings with a one-line notice,
and groups that list whole command summaries."""

import io
import re
import time
import warnings

import click
import pytest
from click.testing import CliRunner

from spm_data.commands.cli_support import (Group, Progress, executor_options, handle_errors, old_spelling,
                                           run_with_progress, tracked)
from spm_data.errors import ShardError, SpmWarning


@click.command()
@click.option("--fail", default="")
@handle_errors
def command(fail):
    warnings.warn("half the shards are missing; skipped", SpmWarning)
    if fail == "spm":
        raise ShardError("cup-00000.h5: field 'K' fails its checksum; the shard is corrupt")
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
    import spm_data.commands.cli_support as support

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


# --------------------------------------------------------------------------- progress


def wait_for(condition, timeout=30.0):
    """Poll ``condition`` until it holds (a state, not a fixed sleep); fail after ``timeout`` s."""
    deadline = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < deadline, "timed out waiting"
        time.sleep(0.005)


class Terminal(io.StringIO):
    def isatty(self):
        return True


LINE = re.compile(r"^render: [\d,]+/5,000 frames, [\d,.]+ frames/s, (\d+ min )?\d+ s left$")


def test_off_a_terminal_a_fed_progress_prints_a_line_with_rate_and_time_left(monkeypatch):
    monkeypatch.setenv("SPM_PROGRESS_EVERY", "0.05")
    out = io.StringIO()
    with Progress("frame", "render", total=5000, stream=out) as progress:
        assert progress.bar is None   # not a terminal: no bar
        progress(1234)
        progress.started = progress.counted - 30   # as if fed over 30 s (at once, the time left would be 0)
        wait_for(lambda: out.getvalue().count("\n") >= 2)
    lines = out.getvalue().splitlines()
    assert all(LINE.match(line) for line in lines), lines
    assert lines[0].startswith("render: 1,234/5,000 frames, ")
    stopped = out.getvalue()
    assert progress._ticker is not None and not progress._ticker.is_alive() and out.getvalue() == stopped


def test_the_line_says_count_rate_and_time_left_and_no_time_left_without_a_total(monkeypatch):
    monkeypatch.setenv("SPM_PROGRESS_EVERY", "3600")
    with Progress("frame", "render", total=5000, stream=io.StringIO()) as progress:
        progress(1234)
        progress.started = time.monotonic() - 30   # as if fed over 30 s
        assert progress.line() == "render: 1,234/5,000 frames, 41.1 frames/s, 1 min 32 s left"
        progress.phase("import coil100", None, "image")
        progress(3)
        progress.started = time.monotonic() - 60
        assert progress.line() == "import coil100: 3 images, 3.0 images/min"
        progress.phase("report", None, None)   # a step that counts nothing
        progress.started = time.monotonic() - 75
        assert progress.line() == "report: 1 min 15 s so far"


def test_the_time_left_counts_down_between_long_items_and_is_not_guessed_once_run_out(monkeypatch):
    """fig5's `fitting: 1/4 splits` once said 48 s left, then 2 min 48 s while nothing ended."""
    monkeypatch.setenv("SPM_PROGRESS_EVERY", "3600")
    with Progress("split", "fitting", total=4, stream=io.StringIO()) as progress:
        assert progress.line() == "fitting: 0/4 splits, 0 splits/s"   # nothing ended: no time left
        progress(1)
        now = time.monotonic()
        progress.started, progress.counted = now - 10, now        # the first split took 10 s
        assert progress.line().endswith(", 30 s left")
        progress.started, progress.counted = now - 25, now - 15   # ... and nothing has ended for 15 s since
        assert progress.line().endswith(", 15 s left")
        progress.started, progress.counted = now - 50, now - 40   # past the guess: none is made
        assert "left" not in progress.line()
        progress(1)   # the next one ends: a new guess from the rate of both
        progress.started = time.monotonic() - 50
        assert progress.line().endswith(", 50 s left")


def test_a_run_shorter_than_the_interval_prints_nothing(monkeypatch):
    monkeypatch.delenv("SPM_PROGRESS_EVERY", raising=False)   # the default: 10 s
    out = io.StringIO()
    with Progress("frame", "render", total=10, stream=out) as progress:
        assert progress.every == 10
        for _ in range(10):
            progress(1)
    assert out.getvalue() == ""


@pytest.mark.parametrize("stream", [io.StringIO, Terminal])
def test_negative_deltas_take_frames_back(stream, monkeypatch):
    monkeypatch.setenv("SPM_PROGRESS_EVERY", "3600")
    with Progress("frame", "render", total=10, stream=stream()) as progress:
        progress(6)
        progress(-4)   # a crashed shard's frames, redone
        assert progress.done == 2 and progress.line().startswith("render: 2/10 frames, ")
        progress(-5)
        assert progress.line().startswith("render: 0/10 frames, 0 frames/s")   # never below 0, no time left
        progress.total = 4   # a new count of the same step
        progress(1)
        assert progress.line().startswith("render: 1/4 frames")


def test_on_a_terminal_it_is_a_bar_and_log_lines_go_to_stdout(capsys):
    out = Terminal()
    with Progress("frame", "render", total=4, stream=out) as progress:
        assert progress._ticker is None
        progress(2)
        progress.write("a log line")
        progress.phase("fitting", 3, "split")
        progress(1)
    assert "render" in out.getvalue() and "1/3" in out.getvalue() and "split" in out.getvalue()
    assert capsys.readouterr().out == "a log line\n"


def test_tracked_counts_the_items():
    assert list(tracked(range(5), "scan", "flip")) == [0, 1, 2, 3, 4]


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

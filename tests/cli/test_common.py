"""cli.common: what both command groups share: one-line errors (exit 1) and warnings, the
summary and exit status of a run, and the executor options."""

import warnings

import click
import pytest
from click.testing import CliRunner

from cli.common import executor_options, handle_errors, run_with_progress
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


def test_other_warnings_go_to_pythons_own_display(monkeypatch):
    import cli.common

    shown = []
    monkeypatch.setattr(cli.common, "_python_showwarning", lambda message, category, *rest: shown.append(
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
    @click.option("--workers", default=1, type=int)
    @click.option("--recycle-after", default=0, type=int)
    @executor_options
    def run(executor):
        seen.append(executor)

    assert CliRunner().invoke(run, ["--workers", "3", "--recycle-after", "2"]).exit_code == 0
    local = seen.pop()
    assert (local.name, local.workers, local.recycle_after) == ("local", 3, 2)
    assert CliRunner().invoke(run, ["--executor", "ray", "--address", "auto", "--task-cpus", "2"]).exit_code == 0
    ray = seen.pop()
    assert (type(ray).__name__, ray.address, ray.task_cpus, ray.workers) == ("RayExecutor", "auto", 2.0, 1)
    r = CliRunner().invoke(run, ["--executor", "slurm"])
    assert r.exit_code == 2 and "'slurm' is not one of 'local', 'ray'" in r.output

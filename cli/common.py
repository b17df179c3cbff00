"""What both command groups share: one-line errors and warnings, progress bars, the
executor options (the only place --workers and friends become an executor)."""

from __future__ import annotations

import functools
import sys
import warnings

import click

from spm_data.errors import SpmError, SpmWarning


def _show_warning(message, category, filename, lineno, file=None, line=None):
    """The library's warnings (SpmWarning) as one ``warning:`` line on stderr."""
    if issubclass(category, SpmWarning):
        click.echo(f"warning: {message}", err=True)
    else:
        _python_showwarning(message, category, filename, lineno, file, line)


_python_showwarning = warnings.showwarning

ALLOW_PARTIAL = click.option(
    "--allow-partial", is_flag=True,
    help="Read a folder a live run is still writing, or whose manifest is missing or disagrees with its "
         "files: only the complete shards, each gap a warning (docs/reliability.md).")


def handle_errors(fn):
    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        from spm_data.jobs.outcome import sigterm_as_interrupt

        warnings.showwarning = _show_warning
        sigterm_as_interrupt()  # SIGTERM stops a run as Ctrl-C does: no lock or partial file left
        try:
            return fn(*args, **kwargs)
        except SpmError as exc:
            click.echo(f"error: {exc}", err=True)
            sys.exit(1)

    return wrapper


class Progress:
    """A tqdm bar the library can feed frame deltas (negative when a crashed shard is redone)."""

    def __init__(self, unit="frame"):
        from tqdm import tqdm

        self.bar = tqdm(total=0, unit=unit, dynamic_ncols=True, disable=None)

    @property
    def total(self):
        return self.bar.total

    @total.setter
    def total(self, value):
        self.bar.total = value
        self.bar.refresh()

    def __call__(self, n):
        self.bar.update(n)

    def close(self):
        self.bar.close()


def run_with_progress(call, report=lambda summary: summary.report()):
    """Run ``call(progress_bar)``, print its summary, exit 130 if interrupted, 1 if shards failed."""
    bar = Progress()
    try:
        summary = call(bar)
    finally:
        bar.close()
    click.echo(report(summary))
    if summary.interrupted:
        sys.exit(130)
    if summary.failed:
        sys.exit(1)


def executor_options(fn):
    """--executor/--address/--task-cpus with --workers and --recycle-after -> one ``executor``
    argument: the only place these options become an executor (library calls take just it)."""
    @functools.wraps(fn)
    def wrapper(*args, executor_name, address, task_cpus, **kwargs):
        from spm_data.jobs import make_executor

        kwargs["executor"] = make_executor(executor_name, workers=kwargs.pop("workers", 1), address=address,
                                           task_cpus=task_cpus, recycle_after=kwargs.pop("recycle_after", 0))
        return fn(*args, **kwargs)

    for option in reversed([
        click.option("--executor", "executor_name", type=click.Choice(["local", "ray"]), default="local",
                      show_default=True, help="Where shard jobs run: local processes, or Ray tasks (docs/scaling.md)."),
        click.option("--address", default=None, help="Ray cluster address (auto or HOST:PORT); default: a local "
                                                     "Ray instance with --workers CPUs."),
        click.option("--task-cpus", default=1.0, show_default=True, type=click.FloatRange(min=0.01),
                     help="CPUs each Ray task reserves (give Blender tasks its Cycles threads)."),
    ]):
        wrapper = option(wrapper)
    return wrapper

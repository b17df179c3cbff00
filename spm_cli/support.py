"""What the commands of both programs (spm_cli/main.py) share: one-line errors and warnings, progress
labelled with the command (spm_data/jobs/progress.py draws it), the executor options (the only place
--workers and friends become an executor), old option spellings kept for one release, and command
groups that print whole summaries."""

from __future__ import annotations

import functools
import sys
import warnings

import click

from spm_data.errors import SpmError, SpmWarning
from spm_data.jobs import progress

CONTEXT = {"help_option_names": ["-h", "--help"], "max_content_width": 100}
# The flag of each option the library names by key in a message (spm_data.errors.Option): occlude's.
FLAGS = {"min": "--min", "max": "--max", "copies": "--copies", "rects": "--rects", "seed": "--seed"}


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
    """A command's shell: the library's errors as one ``error:`` line and exit 1; SIGINT and
    SIGTERM (from the moment the command starts) as one ``interrupted`` line and exit 130 / 143,
    with whatever the library had started undone (its locks released, partial files removed);
    a signal whose KeyboardInterrupt a library swallowed still ends the command that way."""
    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        from spm_data.jobs import outcome

        warnings.showwarning = _show_warning
        outcome.signals_for_work()  # SIGTERM stops a run as Ctrl-C does: no lock or partial file left
        try:
            result = fn(*args, **kwargs)
        except SpmError as exc:
            click.echo(f"error: {exc.named(FLAGS)}", err=True)
            sys.exit(1)
        except KeyboardInterrupt:
            _say_interrupted(outcome)
        except Exception:
            # An error raised while a signal's KeyboardInterrupt unwinds a library (a module left
            # half-imported, a C extension's callback) is the interruption's, not a bug of its own.
            if outcome.received() is None:
                raise
            _say_interrupted(outcome)
        finally:
            outcome.end_of_command()
        if outcome.received() is not None:   # the signal's KeyboardInterrupt was swallowed on the way
            click.echo(f"interrupted ({_signal_name(outcome.received())}) as the command finished; its output "
                       "is complete", err=True)
            sys.exit(outcome.exit_status())
        return result

    return wrapper


def _say_interrupted(outcome) -> None:
    click.echo(f"interrupted ({_signal_name(outcome.received())}); what was complete is kept: run the same "
               "command again to resume", err=True)
    sys.exit(outcome.exit_status())


def _signal_name(signum) -> str:
    import signal

    return signal.Signals(signum).name if signum else "SIGINT"


class Group(click.Group):
    """A command group whose --help lists each command's whole first paragraph (click would cut it
    to fit one line); the commands and subgroups added to it get the same context settings."""

    def __init__(self, *args, **kwargs):
        kwargs.setdefault("context_settings", CONTEXT)
        super().__init__(*args, **kwargs)

    def add_command(self, cmd, name=None):
        if cmd.short_help is None and cmd.help:
            cmd.short_help = " ".join(cmd.help.split("\n\n")[0].split())
        super().add_command(cmd, name)


def _command_label() -> str:
    """The running command without its program ("render", "import coil100"); "progress" outside one."""
    ctx = click.get_current_context(silent=True)
    names = []
    while ctx is not None and ctx.parent is not None:
        names.append(ctx.info_name)
        ctx = ctx.parent
    return " ".join(reversed(names)) or (ctx.info_name if ctx is not None and ctx.info_name else "progress")


class Progress(progress.Progress):
    """A command's :class:`spm_data.jobs.progress.Progress`, labelled with the running command
    ("render", "import coil100") unless given a label."""

    def __init__(self, unit="frame", label=None, total=None, stream=None):
        super().__init__(unit, label or _command_label(), total, stream)


def comma_list(values) -> list:
    """A repeatable option's values, each of which may itself be a comma-separated list, as one list
    (``("a,b", "c")`` -> ``["a", "b", "c"]``): the one list grammar of both programs."""
    return [part.strip() for value in values for part in str(value).split(",") if part.strip()]


def run_with_progress(call, report=lambda summary: summary.report(), unit="frame"):
    """Run ``call(progress)`` (a :class:`Progress`), print its summary, exit 130 if interrupted, 1 if shards failed."""
    bar = Progress(unit)
    try:
        summary = call(bar)
    finally:
        bar.close()
    click.echo(report(summary))
    if summary.interrupted:
        from spm_data.jobs.outcome import exit_status

        sys.exit(exit_status())   # 130 after Ctrl-C, 143 after SIGTERM
    if summary.failed:
        sys.exit(1)


def executor_options(workers: str, recycle_after: int = 0, task_cpus: str = ""):
    """--workers, --recycle-after, --executor, --address and --task-cpus -> one ``executor``
    argument: the only place these options become an executor (library calls take just it).

    ``workers`` says what a worker does on this command, ``recycle_after`` is the command's
    default, ``task_cpus`` is added to --task-cpus' help (e.g. what Blender needs)."""
    def decorator(fn):
        @functools.wraps(fn)
        def wrapper(*args, workers, recycle_after, executor_name, address, task_cpus, **kwargs):
            from spm_data.jobs import make_executor

            kwargs["executor"] = make_executor(executor_name, workers=workers, address=address,
                                               task_cpus=task_cpus, recycle_after=recycle_after)
            return fn(*args, **kwargs)

        for option in reversed([
            click.option("--workers", default=1, show_default=True, type=click.IntRange(min=1, max=1024),
                         help=f"{workers} running at once, at most 1,024 (with --executor ray and no --address: the "
                              "CPUs of the local Ray instance)."),
            click.option("--recycle-after", default=recycle_after, show_default=True,
                         type=click.IntRange(min=0, max=10**6),
                         help="Replace each worker process after this many jobs (0: never; at most 1,000,000); "
                              "bounds leaks."),
            click.option("--executor", "executor_name", type=click.Choice(["local", "ray"]), default="local",
                         show_default=True,
                         help="Where the jobs run: local processes, or Ray tasks (docs/scaling.md)."),
            click.option("--address", default=None, help="Ray cluster address (auto or HOST:PORT); default: a local "
                                                         "Ray instance with --workers CPUs."),
            click.option("--task-cpus", default=1.0, show_default=True, type=click.FloatRange(min=0.01),
                         help=f"CPUs each Ray task reserves.{' ' + task_cpus if task_cpus else ''}"),
        ]):
            wrapper = option(wrapper)
        return wrapper

    return decorator


def old_spelling(flag: str, dest: str, advice: str, *, required: str = "", **option):
    """Keep ``flag``, an option renamed or made positional, for one release: hidden from --help,
    it fills ``dest`` (the new parameter's name) and prints ``warning: FLAG is deprecated; ADVICE``.

    A positional argument the old option stands in for is declared ``required=False``; give its
    metavar as ``required`` and this wrapper reports it missing when neither spelling is given."""
    hidden = "old_" + flag.lstrip("-").replace("-", "_")

    def decorator(fn):
        @functools.wraps(fn)
        def wrapper(*args, **kwargs):
            old = kwargs.pop(hidden)
            if old is not None:
                click.echo(f"warning: {flag} is deprecated; {advice}", err=True)
                if kwargs.get(dest) not in (None, ()):
                    raise click.UsageError(f"{flag} and its new spelling were both given; keep the new one")
                kwargs[dest] = (old,) if isinstance(kwargs.get(dest), tuple) else old
            if required and kwargs.get(dest) in (None, ()):
                raise click.UsageError(f"Missing argument '{required}'.")
            return fn(*args, **kwargs)

        return click.option(flag, hidden, hidden=True, default=None, **option)(wrapper)

    return decorator

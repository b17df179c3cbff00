"""What the commands of both programs (cli.py) share: one-line errors and warnings, progress
(a bar on a terminal, a line every ~10 s elsewhere), the executor options (the only place --workers and friends become an executor), old
option spellings kept for one release, and command groups that print whole summaries."""

from __future__ import annotations

import functools
import os
import sys
import threading
import time
import warnings

import click

from spm_data.errors import SpmError, SpmWarning

CONTEXT = {"help_option_names": ["-h", "--help"], "max_content_width": 100}


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
            click.echo(f"error: {exc}", err=True)
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


def progress_every() -> float:
    """Seconds between progress lines off a terminal: $SPM_PROGRESS_EVERY, default 10."""
    try:
        return max(0.01, float(os.environ.get("SPM_PROGRESS_EVERY") or 10))
    except ValueError:
        return 10.0


def _duration(seconds: float) -> str:
    """"42 s", "1 min 31 s", "2 h 5 min"."""
    s = int(round(seconds))
    if s < 60:
        return f"{s} s"
    return f"{s // 60} min {s % 60} s" if s < 3600 else f"{s // 3600} h {s % 3600 // 60} min"


def _count(n) -> str:
    return f"{n:,}" if float(n).is_integer() else f"{n:,.1f}"


def _command_label() -> str:
    """The running command without its program ("render", "import coil100"); "progress" outside one."""
    ctx = click.get_current_context(silent=True)
    names = []
    while ctx is not None and ctx.parent is not None:
        names.append(ctx.info_name)
        ctx = ctx.parent
    return " ".join(reversed(names)) or (ctx.info_name if ctx is not None and ctx.info_name else "progress")


class Progress:
    """Progress of a long step, fed count deltas (negative when a crashed shard's frames are taken
    back): a tqdm bar on a terminal; elsewhere (a log, a pipe) one line on stderr every EVERY
    seconds, the first after EVERY seconds (none for a shorter run), e.g.
    ``render: 1,234/5,000 frames, 41.2 frames/s, 1 min 31 s left`` (no "left" without a total). The
    time left is that of the rate up to the last count, less the time since it: between the ends of
    a few long items (splits) it counts down, and once it runs out it is left out, never a guess
    that grows while nothing ends.

    EVERY: None reads $SPM_PROGRESS_EVERY (default 10 s). ``phase(label, total, unit)`` starts
    a command's next step (a new count); setting ``total`` starts a new count of the same step;
    a phase with ``unit`` None counts nothing ("report: 25 s so far")."""

    EVERY = None

    def __init__(self, unit="frame", label=None, total=None, stream=None):
        self.stream = stream if stream is not None else sys.stderr
        self.every = self.EVERY or progress_every()
        self._lock, self._stop = threading.Lock(), threading.Event()
        self._start(label or _command_label(), total, unit)
        self.bar = self._ticker = None
        if getattr(self.stream, "isatty", lambda: False)():
            from tqdm import tqdm

            self.bar = tqdm(total=total, unit=unit or "it", desc=self.label, dynamic_ncols=True, file=self.stream)
        else:
            self._ticker = threading.Thread(target=self._tick, name="spm-progress", daemon=True)
            self._ticker.start()

    def _start(self, label, total, unit):
        with self._lock:
            self.label, self._total, self.unit, self.done = label, total, unit, 0
            self.started = self.counted = time.monotonic()   # counted: when the count last grew

    @property
    def total(self):
        return self._total

    @total.setter
    def total(self, value):
        self.phase(self.label, value, self.unit)

    def phase(self, label, total=None, unit="frame"):
        """Start the next step: ``label``, ``total`` (None: unknown) of ``unit``, counted from 0."""
        self._start(label, total, unit)
        if self.bar is not None:
            self.bar.unit, self.bar.desc = unit or "it", label
            self.bar.reset(total=total)

    def __call__(self, n=1):
        with self._lock:
            self.done += n
            if n > 0:
                self.counted = time.monotonic()
        if self.bar is not None:
            self.bar.update(n)

    def line(self) -> str:
        """The progress line as it stands (what is printed off a terminal)."""
        with self._lock:
            label, unit, total, done = self.label, self.unit, self._total, max(self.done, 0)
            now = time.monotonic()
            elapsed, counting = now - self.started, self.counted - self.started
        if unit is None:
            return f"{label}: {_duration(elapsed)} so far"
        units = unit + ("es" if unit.endswith(("s", "x", "ch", "sh")) else "s")
        rate = done / elapsed if elapsed > 0 else 0.0
        speed = (f"{rate:,.1f} {units}/s" if rate >= 0.1 else f"0 {units}/s" if rate == 0 else
                 f"{rate * 60:.1f} {units}/min")
        # Time left at the rate of the counts so far, less the time since the last one: it counts down
        # while a long item runs (a split) instead of growing, and is not guessed once that has run out.
        left = (total - done) * counting / done - (now - self.counted) if total and 0 < done < total else 0
        left = f", {_duration(left)} left" if counting > 0 and left >= 0.5 else ""
        return f"{label}: {_count(done)}{f'/{_count(total)}' if total is not None else ''} {units}, {speed}{left}"

    def _tick(self):
        while not self._stop.wait(self.every):
            try:
                self.stream.write(self.line() + "\n")
                self.stream.flush()
            except (OSError, ValueError):   # the stream went away (a closed pipe): stop saying
                return

    def write(self, message: str):
        """A log line on stdout that does not break the bar."""
        if self.bar is not None:
            self.bar.write(message)
        else:
            click.echo(message)

    def close(self):
        self._stop.set()
        if self._ticker is not None and self._ticker is not threading.current_thread():
            self._ticker.join()
        if self.bar is not None:
            self.bar.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def stage(label: str, total=None, unit: str | None = None) -> Progress:
    """A script's step: ``label`` on stderr now, and a :class:`Progress` of it (a context manager)
    to feed counts of ``unit``, or, with ``unit`` None, whose lines say how long the step has run."""
    click.echo(label, err=True)
    return Progress(unit, label, total)


def tracked(items, label: str, unit: str = "item", total=None):
    """Yield ``items`` after a stage line, with a :class:`Progress` of them (for loops in scripts)."""
    with stage(label, total if total is not None else len(items) if hasattr(items, "__len__") else None, unit) \
            as progress:
        for item in items:
            yield item
            progress(1)


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
            click.option("--recycle-after", default=recycle_after, show_default=True, type=click.IntRange(min=0, max=10**6),
                         help="Replace each worker process after this many jobs (0: never; at most 1,000,000); "
                              "bounds leaks."),
            click.option("--executor", "executor_name", type=click.Choice(["local", "ray"]), default="local",
                         show_default=True, help="Where the jobs run: local processes, or Ray tasks (docs/scaling.md)."),
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

"""What local and Ray executors share: a job's outcome, error text, Ctrl-C handling."""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading
import warnings
from dataclasses import dataclass

from spm_data.errors import SpmError, SpmWarning


@dataclass
class JobOutcome:
    job: object
    result: object = None
    error: str | None = None
    attempts: int = 1


# The last SIGINT or SIGTERM this process was sent while a command worked (its number), so the
# command exits 128 + that number even where the KeyboardInterrupt it raised was swallowed (a
# finaliser, a library's ``except BaseException``), and a run that had not started its work
# stops at its first safe point instead of running to the end.
_received: list = [None]
# Set by a signal raised as KeyboardInterrupt outside a deferred run; the next deferred run
# stops at once (that KeyboardInterrupt may have been swallowed). Cleared when acted on.
_pending: list = [False]
BEFORE_WORK = "interrupted before any work began; nothing was written"


# Where Python runs weakref callbacks: a WeakValueDictionary's ``remove``, a WeakSet's ``_remove``,
# ``weakref.finalize``'s ``__call__``; they run whenever an object is freed, from any line.
_CALLBACK_FILES = ("weakref.py", "_weakrefset.py")


def _in_finaliser(frame) -> bool:
    """Whether the signal landed in a ``__del__`` or a weakref callback (or code either called):
    an exception raised there is printed as "Exception ignored in: <function
    WeakValueDictionary.__init__.<locals>.remove …> Traceback" and lost, so the signal is only
    recorded, and acted on at the next safe point or when the command ends."""
    for _ in range(64):
        if frame is None:
            return False
        code = frame.f_code
        if code.co_name == "__del__" or os.path.basename(code.co_filename) in _CALLBACK_FILES:
            return True
        frame = frame.f_back
    return False


def _raise_interrupt(signum, frame):
    _received[0], _pending[0] = signum, True
    if _in_finaliser(frame):
        return   # acted on at the next safe point (a pool's loop) or when the command ends
    raise KeyboardInterrupt


def received() -> int | None:
    """The signal (number) that interrupted this command, or None."""
    return _received[0]


def end_of_command() -> None:
    """Forget a signal this command already acted on (the next command in this process starts clean)."""
    _pending[0] = False


def exit_status() -> int:
    """The exit status of an interrupted command: 130 for SIGINT (Ctrl-C), 143 for SIGTERM."""
    return 128 + int(_received[0] or signal.SIGINT)


def _stop_before_work(signum, frame):
    os.write(2, f"{BEFORE_WORK} ({signal.Signals(signum).name})\n".encode())
    os._exit(128 + signum)   # nothing was made yet: no lock, no partial file, nothing to undo


def catch_signals_early() -> None:
    """From the first line the ``spm`` and ``spm-data`` programs run (cli.py, before any other
    import): SIGINT and SIGTERM end the process at once with one line and 130 / 143, instead of
    a KeyboardInterrupt traceback from inside an import, click's "Aborted!", or a signal lost in
    a library's handler. :func:`signals_for_work` takes over when the command starts its work."""
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, _stop_before_work)
        signal.signal(signal.SIGTERM, _stop_before_work)


def signals_for_work() -> None:
    """When a command starts its work (spm_cli.support.handle_errors): SIGINT and SIGTERM raise
    KeyboardInterrupt (recorded, see ``received``), which the command turns into its one-line
    message, exit 130 / 143, the run's lock released and its partial files removed. Only from
    the main thread, and only over our early handler or Python's defaults (a caller's own
    handler is kept)."""
    if threading.current_thread() is not threading.main_thread():
        return
    _received[0], _pending[0] = None, False
    if signal.getsignal(signal.SIGINT) in (_stop_before_work, signal.default_int_handler):
        signal.signal(signal.SIGINT, _raise_interrupt)
    if signal.getsignal(signal.SIGTERM) in (_stop_before_work, signal.SIG_DFL):
        signal.signal(signal.SIGTERM, _raise_interrupt)


def sigterm_as_interrupt() -> None:
    """SIGTERM stops this process as Ctrl-C does (the name of :func:`signals_for_work` before)."""
    signals_for_work()


@contextlib.contextmanager
def deferred_interrupt():
    """Turn the first Ctrl-C (and SIGTERM, when signals_for_work made it one) into a flag checked
    at safe points (after a frame, in the pool loop), raised there as KeyboardInterrupt. A
    signal raised directly can land inside a finaliser or a C callback, where Python prints
    "Exception ignored" and the run goes on; a second signal interrupts at once. A signal that
    arrived before (and was swallowed) sets the flag at once. Yields the flag."""
    stop = threading.Event()
    before = signal.getsignal(signal.SIGINT)
    if threading.current_thread() is not threading.main_thread() or \
            before not in (signal.default_int_handler, _raise_interrupt):
        yield stop  # not ours to change (a thread, or a caller with its own handler)
        return

    def on_signal(signum, frame):
        _received[0] = signum
        if stop.is_set() and not _in_finaliser(frame):
            raise KeyboardInterrupt
        stop.set()

    if _pending[0]:
        _pending[0] = False
        stop.set()   # interrupted earlier (planning, imports) and the KeyboardInterrupt may have been lost
    term = signal.getsignal(signal.SIGTERM)
    signal.signal(signal.SIGINT, on_signal)
    if term is _raise_interrupt:
        signal.signal(signal.SIGTERM, on_signal)
    try:
        yield stop
    finally:
        signal.signal(signal.SIGINT, before)
        if term is _raise_interrupt:
            signal.signal(signal.SIGTERM, term)


def warnings_as_lines() -> None:
    """In a worker process: the library's warnings (SpmWarning) as one ``warning: …`` line on its
    stderr (the command's), as the command prints its own (spm_cli.support), not Python's two-line
    ``FILE:LINE: SpmWarning: …`` format; other warnings as Python shows them."""
    python = warnings.showwarning

    def show(message, category, filename, lineno, file=None, line=None):
        if issubclass(category, SpmWarning):
            sys.stderr.write(f"warning: {message}\n")
            sys.stderr.flush()
        else:
            python(message, category, filename, lineno, file, line)

    warnings.showwarning = show


def error_text(exc: BaseException) -> str:
    """A job's exception as one line: our own message alone, any other exception with its type."""
    return str(exc) if isinstance(exc, SpmError) else f"{type(exc).__name__}: {exc}"


def is_blender_script_dir(path: str) -> bool:
    parts = path.replace("\\", "/").split("/")
    return "scripts" in parts and ("bpy" in parts or "blender" in parts)


def probe_job(job, report):
    """A job that does nothing but say which process ran it (benchmarks, tests)."""
    import os

    report(1)
    return {"job": job, "pid": os.getpid()}

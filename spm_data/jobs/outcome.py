"""What local and Ray executors share: a job's outcome, error text, Ctrl-C handling."""

from __future__ import annotations

import contextlib
import signal
import threading
from dataclasses import dataclass

from spm_data.errors import SpmError


@dataclass
class JobOutcome:
    job: object
    result: object = None
    error: str | None = None
    attempts: int = 1


def _raise_interrupt(signum, frame):
    raise KeyboardInterrupt


def sigterm_as_interrupt() -> None:
    """Make SIGTERM stop this process as Ctrl-C does (a KeyboardInterrupt: the run's lock
    released, partial files removed, the manifest written); for command-line entry points.
    Only from the main thread, and only over the default handler."""
    if threading.current_thread() is threading.main_thread() and \
            signal.getsignal(signal.SIGTERM) is signal.SIG_DFL:
        signal.signal(signal.SIGTERM, _raise_interrupt)


@contextlib.contextmanager
def deferred_interrupt():
    """Turn the first Ctrl-C (and SIGTERM, when sigterm_as_interrupt made it one) into a
    flag checked at safe points (after a frame, in the pool loop), raised there as
    KeyboardInterrupt. A signal raised directly can land inside a finaliser or a C
    callback, where Python prints "Exception ignored" and the run goes on; a second
    signal interrupts at once. Yields the flag."""
    stop = threading.Event()
    if threading.current_thread() is not threading.main_thread() or \
            signal.getsignal(signal.SIGINT) is not signal.default_int_handler:
        yield stop  # not ours to change (a thread, or a caller with its own handler)
        return

    def on_signal(signum, frame):
        if stop.is_set():
            raise KeyboardInterrupt
        stop.set()

    term = signal.getsignal(signal.SIGTERM)
    signal.signal(signal.SIGINT, on_signal)
    if term is _raise_interrupt:
        signal.signal(signal.SIGTERM, on_signal)
    try:
        yield stop
    finally:
        signal.signal(signal.SIGINT, signal.default_int_handler)
        if term is _raise_interrupt:
            signal.signal(signal.SIGTERM, term)


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

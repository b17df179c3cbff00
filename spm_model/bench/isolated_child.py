"""The child of spm_model/bench/isolation.py: the process a split's methods run in. It takes its
parent's sys.path, ignores Ctrl-C (the user's command owns it), exits when its parent is gone,
runs on one BLAS thread (as every benchmark job), and answers with plain arrays and one-line
reasons (isolation.encode), whatever a method raised or did."""

from __future__ import annotations

import importlib
import os
import pickle
import signal
import threading
import time
from dataclasses import asdict
from multiprocessing.connection import Connection

from spm_model.errors import ModelError
from spm_model.bench.fitting import call_failure, construct, found_flags, make_methods
from spm_model.bench.isolation import READY, encode
from spm_model.bench.plugin_refs import resolve

WATCH_EVERY = 0.5   # seconds between the child's looks at whether its parent is alive


def _watch_parent(parent: int) -> None:
    """Exit this child once its parent is gone (killed, or ended without closing it)."""
    while os.getppid() == parent:
        time.sleep(WATCH_EVERY)
    os._exit(1)


def child_main(read_fd: int, write_fd: int, parent: int, work: str = "spm_model.bench.isolated_child:serve") -> None:
    """The child, started with its parent's sys.path: ``work`` ('MODULE:FUNCTION', called with the
    two ends of the pipe: the benchmark's :func:`serve` or check-estimator's) until it returns."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)   # only the user's command owns Ctrl-C
    down = Connection(read_fd, writable=False)
    up = Connection(write_fd, readable=False)
    threading.Thread(target=_watch_parent, args=(parent,), daemon=True).start()
    from threadpoolctl import threadpool_limits

    module, function = work.split(":")
    serve_work = getattr(importlib.import_module(module), function)
    try:
        up.send_bytes(READY)
        with threadpool_limits(limits=1, user_api="blas"):   # as bench_job: results independent of the cores
            serve_work(down, up)
        up.close()
    except (EOFError, OSError, Closed):
        pass   # the parent closed the pipe or is gone (a spare never used, an interrupted run): nothing to say
    os._exit(0)   # a plug-in's threads or atexit handlers never keep it alive


class Closed(Exception):
    """The parent closed this child before giving it work (a spare it did not need)."""


def first_message(down):
    """The work's first message; Closed when the parent sent None instead (EstimatorProcess.close)."""
    message = down.recv()
    if message is None:
        raise Closed
    return message


def send(up, header: dict, arrays=()) -> None:
    for message in encode(header, arrays):
        up.send_bytes(message)


def serve(down, up) -> None:
    """("start", (seed, model params, {plug-in name: class}), names, frames, poses, memo folder), then
    test chunks until None: construct and fit each method of ``names``, then predict every chunk with
    each fitted one."""
    from spm_model.base.feature_memo import use_folder
    from spm_model.methods.registry import check_predictions

    _, (run, params, plugins), names, frames, poses, memo = first_message(down)
    use_folder(memo)
    built = make_methods(run, params, [n for n in names if n not in plugins])   # share SPM with KNN
    fitted = {}
    for name in names:
        try:
            method = built[name] if name in built else construct(resolve(plugins[name]))
            model = method.fit(frames, poses.copy())
            why = None if model is not None else "fit(frames, poses) returned None; it must return self"
        except BaseException as exc:  # noqa: BLE001 - SystemExit and KeyboardInterrupt too: declined
            model, why = None, call_failure(exc)
        if why is None:
            fitted[name] = model
        send(up, {"name": name, "why": why})
    while True:
        chunk = down.recv()
        if chunk is None:
            return
        for name, model in list(fitted.items()):
            try:
                pred = check_predictions(name, model.predict(chunk), len(chunk))
            except BaseException as exc:  # noqa: BLE001 - as in fit
                del fitted[name]
                send(up, {"name": name, "why": call_failure(exc, "predict: ")})
                continue
            flags = found_flags(model, chunk)
            send(up, {"name": name, "why": None}, [pred] + ([] if flags is None else [flags]))


def describe_one(spec: str) -> dict:
    """What plugin_refs.describe reads of one class, as the child sends it (needs, or why NEEDS is
    wrong; whether it is deterministic; why pickle refuses it, if it does)."""
    from spm_model.base.estimator import needs_of
    from spm_model.methods.registry import load_estimator_class

    cls = load_estimator_class(spec)
    try:
        needs, needs_error = asdict(needs_of(cls)), None
    except ModelError as exc:
        needs, needs_error = None, f"--estimator {spec}: {exc}"
    try:
        pickle.dumps(cls)
        unpicklable = None
    except Exception as exc:  # noqa: BLE001 - reported as a failed check by check-estimator
        unpicklable = f"{type(exc).__name__}: {exc}"
    return {"needs": needs, "needs_error": needs_error, "unpicklable": unpicklable,
            "deterministic": getattr(cls, "DETERMINISTIC", False) is True}


def serve_describe(down, up) -> None:
    """The child's work: a list of specs; for each, its description or the error (one line)."""
    for spec in first_message(down):
        try:
            send(up, {"name": spec, **describe_one(spec)})
        except ModelError as exc:
            send(up, {"name": spec, "error": str(exc)})
        except BaseException as exc:  # noqa: BLE001 - its module's code: one line, whatever it raised
            send(up, {"name": spec, "error": f"--estimator {spec}: {call_failure(exc)}"})

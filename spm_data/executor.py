"""Run shard-sized jobs in worker processes that may crash without taking the run down.

Each worker has its own pipe, so the parent always knows which job a worker
holds: a worker that dies (SIGKILL, out of memory, a segfault in a renderer)
loses only that job, which is retried ``retries`` times and then reported;
the other jobs go on. Workers retire after ``recycle_after`` jobs so a slow
leak in a renderer cannot grow without bound. ``workers=0`` runs in-process.
"""

from __future__ import annotations

import contextlib
import multiprocessing as mp
import signal
import sys
import threading
from dataclasses import dataclass, field
from multiprocessing.connection import wait

from spm_data.errors import SpmError


@dataclass
class JobOutcome:
    job: object
    result: object = None
    error: str | None = None
    attempts: int = 1


@dataclass
class _Worker:
    process: mp.Process
    conn: object
    job_id: int | None = None
    done: int = 0
    progress: dict = field(default_factory=dict)


@contextlib.contextmanager
def deferred_interrupt():
    """Turn the first Ctrl-C into a flag checked at safe points (after a frame, in
    the pool loop), raised there as KeyboardInterrupt. A signal raised directly can
    land inside a finaliser or a C callback, where Python prints "Exception ignored"
    and the run goes on; a second Ctrl-C interrupts at once. Yields the flag."""
    stop = threading.Event()
    if threading.current_thread() is not threading.main_thread() or \
            signal.getsignal(signal.SIGINT) is not signal.default_int_handler:
        yield stop  # not ours to change (a thread, or a caller with its own handler)
        return

    def on_sigint(signum, frame):
        if stop.is_set():
            raise KeyboardInterrupt
        stop.set()

    signal.signal(signal.SIGINT, on_sigint)
    try:
        yield stop
    finally:
        signal.signal(signal.SIGINT, signal.default_int_handler)


def _describe(exc: BaseException) -> str:
    return str(exc) if isinstance(exc, SpmError) else f"{type(exc).__name__}: {exc}"


def _blender_script_dir(path: str) -> bool:
    parts = path.replace("\\", "/").split("/")
    return "scripts" in parts and ("bpy" in parts or "blender" in parts)


def _worker_main(fn, conn, recycle_after):
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent owns Ctrl-C and stops us
    # A parent that imported bpy hands us Blender's script folders on sys.path;
    # with them, `import bpy` here would find Blender's scripts/modules/bpy instead.
    sys.path[:] = [p for p in sys.path if not _blender_script_dir(p)]
    done = 0
    while True:
        item = conn.recv()
        if item is None:
            return
        job_id, job = item
        try:
            result = fn(job, lambda n, job_id=job_id: conn.send(("progress", job_id, n)))
            conn.send(("done", job_id, result))
        except BaseException as exc:  # noqa: BLE001 - reported to the parent, never swallowed
            conn.send(("error", job_id, _describe(exc)))
        done += 1
        if recycle_after and done >= recycle_after:
            conn.send(("retire", None, None))
            return


def run_jobs(fn, jobs, *, workers=1, retries=1, recycle_after=0, on_progress=None, on_outcome=None,
             on_worker_death=None):
    """Run ``fn(job, report)`` for every job; ``report(n)`` advances progress by n.

    Returns a list of :class:`JobOutcome` in job order. ``on_progress(n)`` gets
    progress deltas (negative when a crashed job's frames are lost);
    ``on_outcome(outcome)`` is called as each job finishes; ``on_worker_death(job)``
    when a worker dies holding ``job`` (to clean up what it left).
    """
    with deferred_interrupt() as stop:
        return _run_jobs(fn, list(jobs), workers, retries, recycle_after, on_progress, on_outcome,
                         on_worker_death, stop)


def _run_jobs(fn, jobs, workers, retries, recycle_after, on_progress, on_outcome, on_worker_death, stop):
    outcomes: list[JobOutcome | None] = [None] * len(jobs)
    report = on_progress or (lambda n: None)

    def progress(n):
        report(n)
        if stop.is_set():
            raise KeyboardInterrupt

    if workers <= 0:
        for i, job in enumerate(jobs):
            try:
                outcomes[i] = JobOutcome(job, result=fn(job, progress))
            except SpmError as exc:
                outcomes[i] = JobOutcome(job, error=_describe(exc))
            if on_outcome:
                on_outcome(outcomes[i])
        return outcomes

    ctx = mp.get_context("spawn")  # never fork a process that may hold a GL or Blender context
    queue = list(range(len(jobs)))
    attempts = [0] * len(jobs)
    pool: dict[int, _Worker] = {}
    next_id = 0

    def start_worker():
        nonlocal next_id
        parent, child = ctx.Pipe()
        proc = ctx.Process(target=_worker_main, args=(fn, child, recycle_after), daemon=True)
        proc.start()
        child.close()
        pool[next_id] = _Worker(proc, parent)
        next_id += 1

    def finish(job_id, result=None, error=None):
        outcomes[job_id] = JobOutcome(jobs[job_id], result=result, error=error, attempts=attempts[job_id])
        if on_outcome:
            on_outcome(outcomes[job_id])

    def lost(w: _Worker, why: str):
        job_id = w.job_id
        w.job_id = None
        if job_id is None:
            return
        progress(-w.progress.pop(job_id, 0))
        if on_worker_death:
            on_worker_death(jobs[job_id])
        if attempts[job_id] <= retries:
            queue.insert(0, job_id)
        else:
            finish(job_id, error=f"worker died ({why}) after {attempts[job_id]} attempts")

    try:
        for _ in range(min(workers, len(jobs))):
            start_worker()
        while any(o is None for o in outcomes):
            for w in list(pool.values()):
                if w.job_id is None and queue and w.process.is_alive():
                    w.job_id = queue.pop(0)
                    attempts[w.job_id] += 1
                    w.progress[w.job_id] = 0
                    try:
                        w.conn.send((w.job_id, jobs[w.job_id]))
                    except (BrokenPipeError, OSError):
                        pass  # its death is noticed below
            if stop.is_set():
                raise KeyboardInterrupt
            ready = wait([w.conn for w in pool.values()] + [w.process.sentinel for w in pool.values()], timeout=0.5)
            for wid, w in list(pool.items()):
                dead = False
                if w.conn in ready:
                    try:
                        while w.conn.poll():
                            kind, job_id, payload = w.conn.recv()
                            if kind == "progress":
                                w.progress[job_id] = w.progress.get(job_id, 0) + payload
                                progress(payload)
                            elif kind in ("done", "error"):
                                w.job_id = None
                                w.progress.pop(job_id, None)
                                finish(job_id, **({"result": payload} if kind == "done" else {"error": payload}))
                            elif kind == "retire":
                                dead = True
                    except (EOFError, OSError):
                        dead = True
                if dead or not w.process.is_alive():
                    w.process.join(timeout=5)
                    code = w.process.exitcode
                    why = f"signal {-code}" if code is not None and code < 0 else f"exit code {code}"
                    lost(w, why)
                    w.conn.close()
                    del pool[wid]
                    busy = sum(1 for x in pool.values() if x.job_id is not None)
                    if queue and len(pool) < workers and len(pool) < len(queue) + busy:
                        start_worker()
            if not pool and queue:
                start_worker()
    finally:
        for w in pool.values():
            try:
                w.conn.send(None)
            except (BrokenPipeError, OSError):
                pass
        for w in pool.values():
            w.process.join(timeout=2)
            if w.process.is_alive():
                w.process.terminate()
                w.process.join(timeout=5)
            if w.job_id is not None and on_worker_death:
                on_worker_death(jobs[w.job_id])
    return outcomes


def probe_job(job, report):
    """A job that does nothing but say which process ran it (benchmarks, tests)."""
    import os

    report(1)
    return {"job": job, "pid": os.getpid()}


class LocalExecutor:
    """Worker processes on this machine (the default): ``run_jobs`` with ``workers``
    processes; ``in_process`` runs in this process when workers <= 1 (not for Blender)."""

    name = "local"

    def __init__(self, workers: int = 1, retries: int = 1, recycle_after: int = 0):
        self.workers = workers
        self.retries = retries
        self.recycle_after = recycle_after

    def run(self, fn, jobs, *, in_process=True, on_progress=None, on_outcome=None, on_worker_death=None):
        workers = 0 if (in_process and self.workers <= 1) else max(1, self.workers)
        return run_jobs(fn, jobs, workers=workers, retries=self.retries, recycle_after=self.recycle_after,
                        on_progress=on_progress, on_outcome=on_outcome, on_worker_death=on_worker_death)


def make_executor(name: str = "local", *, workers: int = 1, address: str | None = None,
                  task_cpus: float = 1.0, retries: int = 1, recycle_after: int = 0):
    """``local`` (processes here) or ``ray`` (spm_data.ray_executor; needs the ``ray`` extra)."""
    if name == "local":
        return LocalExecutor(workers=workers, retries=retries, recycle_after=recycle_after)
    if name == "ray":
        from spm_data.ray_executor import RayExecutor

        return RayExecutor(address=address, workers=workers, task_cpus=task_cpus, retries=retries,
                           recycle_after=recycle_after)
    raise SpmError(f"executor must be 'local' or 'ray', got {name!r}")

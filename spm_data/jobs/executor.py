"""Run shard-sized jobs in worker processes that may crash without taking the run down.

Each worker has its own pipe, so the parent always knows which job a worker
holds: a worker that dies (SIGKILL, out of memory, a segfault in a renderer)
loses only that job, which is retried ``retries`` times and then reported;
the other jobs go on. Workers retire after ``recycle_after`` jobs so a slow
leak in a renderer cannot grow without bound. ``workers=0`` runs in-process;
``parent_works``: this process is one of the workers (for light jobs, whose
start-up in a new process is a large share: it works while the others start).
``gpus``: each worker process renders on one of them, in turn (render's --gpus).
"""

from __future__ import annotations

import multiprocessing as mp
import os
import signal
import sys
from dataclasses import dataclass, field
from contextlib import contextmanager
from multiprocessing.connection import wait

from spm_data.errors import SpmError
from spm_data.jobs.outcome import (JobOutcome, deferred_interrupt, error_text, is_blender_script_dir,
                                   warnings_as_lines)


@dataclass
class _Worker:
    process: mp.Process
    conn: object
    job_id: int | None = None
    done: int = 0
    progress: dict = field(default_factory=dict)
    ready: bool = False  # it said so (its imports done)
    slot: int = 0        # which of the pool's places it fills (its GPU, with gpus)


BLAS_THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")
WORKER_CORES = "SPM_WORKER_CORES"  # a spawned worker's share of the cores (render's pipeline threads)


def blas_threads(workers: int) -> dict:
    """Environment for a spawned worker's BLAS: the cores shared among ``workers`` processes
    (at least one thread each), for each variable the user has not set. OpenBLAS starts a
    thread per core in every process; with two workers on two cores their threads spin
    against each other and SPM's small matrix products took 2-3 times the CPU."""
    threads = str(max(1, (os.cpu_count() or 1) // max(1, workers)))
    return {name: threads for name in BLAS_THREAD_VARIABLES if name not in os.environ}


def worker_environment(workers: int, slot: int = 0, gpus=()) -> dict:
    """Environment for the spawned worker in place ``slot`` of ``workers``: blas_threads, its
    share of the cores (WORKER_CORES) and, with ``gpus``, its GPU (GPU_VARIABLE): gpus[slot mod
    len(gpus)], so the workers spread over the GPUs evenly, a replaced worker on its place's GPU."""
    env = {**blas_threads(workers), WORKER_CORES: str(max(1, (os.cpu_count() or 1) // max(1, workers)))}
    return {**env, **gpu_environment(gpus, slot)}


def gpu_environment(gpus, slot: int = 0) -> dict:
    """{GPU_VARIABLE: gpus[slot mod len(gpus)]}, or {} without gpus."""
    if not gpus:
        return {}
    from spm_data.render.base import GPU_VARIABLE  # only with GPUs: the render layer costs 0.4 s to import

    return {GPU_VARIABLE: str(gpus[slot % len(gpus)])}


@contextmanager
def environment(values: dict):
    """``values`` in os.environ for the block (a spawned child takes the environment as it
    starts; in-process jobs read it), then the environment as it was."""
    before = {name: os.environ.get(name) for name in values}
    os.environ.update(values)
    try:
        yield
    finally:
        for name, value in before.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value


@contextmanager
def _sigint_held():
    """SIGINT blocked on this thread while a worker is spawned: the child inherits the mask, so a
    Ctrl-C to the process group during the child's start-up (imports: a second or more) waits
    instead of printing a KeyboardInterrupt traceback from the child, and _worker_main then
    ignores it. The parent's own SIGINT is not lost: another thread takes it, or this one when
    the mask is restored, a few milliseconds later."""
    if not hasattr(signal, "pthread_sigmask"):
        yield
        return
    from multiprocessing import resource_tracker

    # Started by the first spawn, the resource tracker unblocks SIGINT when it has started
    # (CPython 3.11), which would undo the mask for that first worker: start it before.
    resource_tracker.ensure_running()
    before = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, before)


def _worker_main(fn, conn, recycle_after):
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent owns Ctrl-C and stops us
    if hasattr(signal, "pthread_sigmask"):   # started with SIGINT blocked (_sigint_held): ignored from now on
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
    # A parent that imported bpy hands us Blender's script folders on sys.path;
    # with them, `import bpy` here would find Blender's scripts/modules/bpy instead.
    sys.path[:] = [p for p in sys.path if not is_blender_script_dir(p)]
    warnings_as_lines()
    conn.send(("ready", None, None))
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
            conn.send(("error", job_id, error_text(exc)))
        done += 1
        if recycle_after and done >= recycle_after:
            conn.send(("retire", None, None))
            return


def run_jobs(fn, jobs, *, workers=1, retries=1, recycle_after=0, on_progress=None, on_outcome=None,
             on_worker_death=None, parent_works=False, gpus=()):
    """Run ``fn(job, report)`` for every job; ``report(n)`` advances progress by n.
    parent_works: with ``workers`` > 1, this process runs jobs too and ``workers - 1`` are
    spawned; a spawned worker gets a job once it is ready (its imports done). gpus: GPU
    indices, one per spawned worker in turn (worker_environment); in-process jobs use the first.

    Returns a list of :class:`JobOutcome` in job order. ``on_progress(n)`` gets
    progress deltas (negative when a crashed job's frames are lost);
    ``on_outcome(outcome)`` is called as each job finishes; ``on_worker_death(job)``
    when a worker dies holding ``job`` (to clean up what it left).
    """
    with deferred_interrupt() as stop:
        return _run_jobs(fn, list(jobs), workers, retries, recycle_after, on_progress, on_outcome,
                         on_worker_death, stop, parent_works, tuple(gpus))


def _run_jobs(fn, jobs, workers, retries, recycle_after, on_progress, on_outcome, on_worker_death, stop,
              parent_works=False, gpus=()):
    if workers <= 0 or (parent_works and workers == 1):
        with environment(gpu_environment(gpus)):
            return _run_in_process(fn, jobs, on_progress, on_outcome, stop)
    pool = _Pool(fn, jobs, workers, retries, recycle_after, on_progress, on_outcome, on_worker_death, stop,
                 parent_works, gpus)
    try:
        pool.run()
    finally:
        pool.shut_down()
    return pool.outcomes


def _checked_progress(on_progress, stop):
    """``report(n)`` for jobs: passes progress on, then stops the run at a Ctrl-C."""
    report = on_progress or (lambda n: None)

    def progress(n):
        report(n)
        if stop.is_set():
            raise KeyboardInterrupt
    return progress


def _run_in_process(fn, jobs, on_progress, on_outcome, stop) -> list:
    progress = _checked_progress(on_progress, stop)
    outcomes = []
    for job in jobs:
        outcomes.append(_run_here(fn, job, progress))
        if on_outcome:
            on_outcome(outcomes[-1])
    return outcomes


def _run_here(fn, job, progress, attempts=1) -> JobOutcome:
    """One job in this process: its outcome (an SpmError is its error; anything else is raised)."""
    try:
        return JobOutcome(job, result=fn(job, progress), attempts=attempts)
    except SpmError as exc:
        return JobOutcome(job, error=error_text(exc), attempts=attempts)


class _Pool:
    """Spawned workers, one pipe each, running ``jobs`` to an outcome each: a job whose
    worker dies goes back to the queue (``retries`` times), then fails."""

    def __init__(self, fn, jobs, workers, retries, recycle_after, on_progress, on_outcome, on_worker_death, stop,
                 parent_works=False, gpus=()):
        self.fn, self.jobs, self.workers, self.retries = fn, jobs, workers, retries
        self.recycle_after, self.on_outcome, self.on_worker_death, self.stop = (recycle_after, on_outcome,
                                                                               on_worker_death, stop)
        self.progress = _checked_progress(on_progress, stop)
        self.ctx = mp.get_context("spawn")  # never fork a process that may hold a GL or Blender context
        self.outcomes: list[JobOutcome | None] = [None] * len(jobs)
        self.queue = list(range(len(jobs)))
        self.attempts = [0] * len(jobs)
        self.pool: dict[int, _Worker] = {}
        self.next_id = 0
        self.parent_works = parent_works  # run_jobs' parent_works
        self.gpus = gpus  # run_jobs' gpus
        self.spawned = workers - 1 if parent_works else workers  # processes to keep running

    def run(self) -> None:
        for _ in range(min(self.spawned, len(self.jobs))):
            self.start_worker()
        while any(o is None for o in self.outcomes):
            self.hand_out_jobs()
            if self.stop.is_set():
                raise KeyboardInterrupt
            here = self.parent_works and bool(self.queue)
            if here:  # this process takes the next job itself, then looks at the workers' messages
                job_id = self.queue.pop(0)
                self.attempts[job_id] += 1
                self.finish(job_id, outcome=_run_here(self.fn, self.jobs[job_id], self.progress,
                                                      self.attempts[job_id]))
            conns = [w.conn for w in self.pool.values()] + [w.process.sentinel for w in self.pool.values()]
            ready = wait(conns, timeout=0 if here else 0.5)
            for wid, w in list(self.pool.items()):
                retired = self.read_messages(w) if w.conn in ready else False
                if retired or not w.process.is_alive():
                    self.replace_worker(wid, w)
            if not self.pool and self.queue and self.spawned:
                self.start_worker()

    def start_worker(self) -> None:
        parent, child = self.ctx.Pipe()
        proc = self.ctx.Process(target=_worker_main, args=(self.fn, child, self.recycle_after), daemon=True)
        slot = min(set(range(len(self.pool) + 1)) - {w.slot for w in self.pool.values()})  # a free place
        with environment(worker_environment(self.workers, slot, self.gpus)), _sigint_held():
            proc.start()
        child.close()
        self.pool[self.next_id] = _Worker(proc, parent, slot=slot)
        self.next_id += 1

    def hand_out_jobs(self) -> None:
        for w in list(self.pool.values()):
            if w.job_id is None and self.queue and w.process.is_alive() and (w.ready or not self.parent_works):
                w.job_id = self.queue.pop(0)
                self.attempts[w.job_id] += 1
                w.progress[w.job_id] = 0
                try:
                    w.conn.send((w.job_id, self.jobs[w.job_id]))
                except (BrokenPipeError, OSError):
                    pass  # its death is noticed by the main loop

    def read_messages(self, w: _Worker) -> bool:
        """Take everything ``w`` sent; True when it retired or its pipe broke."""
        try:
            while w.conn.poll():
                kind, job_id, payload = w.conn.recv()
                if kind == "ready":
                    w.ready = True
                elif kind == "progress":
                    w.progress[job_id] = w.progress.get(job_id, 0) + payload
                    self.progress(payload)
                elif kind in ("done", "error"):
                    w.job_id = None
                    w.progress.pop(job_id, None)
                    self.finish(job_id, **({"result": payload} if kind == "done" else {"error": payload}))
                elif kind == "retire":
                    return True
        except (EOFError, OSError):
            return True
        return False

    def replace_worker(self, wid: int, w: _Worker) -> None:
        """Reap a worker that retired or died (its job back to the queue), and start
        another while there is work for it."""
        w.process.join(timeout=5)
        code = w.process.exitcode
        self.lost(w, f"signal {-code}" if code is not None and code < 0 else f"exit code {code}")
        w.conn.close()
        del self.pool[wid]
        busy = sum(1 for x in self.pool.values() if x.job_id is not None)
        if self.queue and len(self.pool) < self.spawned and len(self.pool) < len(self.queue) + busy:
            self.start_worker()

    def finish(self, job_id, result=None, error=None, outcome=None) -> None:
        self.outcomes[job_id] = outcome or JobOutcome(self.jobs[job_id], result=result, error=error,
                                                      attempts=self.attempts[job_id])
        if self.on_outcome:
            self.on_outcome(self.outcomes[job_id])

    def lost(self, w: _Worker, why: str) -> None:
        job_id, w.job_id = w.job_id, None
        if job_id is None:
            return
        self.progress(-w.progress.pop(job_id, 0))
        if self.on_worker_death:
            self.on_worker_death(self.jobs[job_id])
        if self.attempts[job_id] <= self.retries:
            self.queue.insert(0, job_id)
        else:
            self.finish(job_id, error=f"worker died ({why}) after {self.attempts[job_id]} attempts")

    def shut_down(self) -> None:
        """Ask every worker to stop, then make sure it has; a job a worker still held
        (an interrupted run) is cleaned up through on_worker_death."""
        for w in self.pool.values():
            try:
                w.conn.send(None)
            except (BrokenPipeError, OSError):
                pass
        for w in self.pool.values():
            w.process.join(timeout=2)
            if w.process.is_alive():
                w.process.terminate()
                w.process.join(timeout=5)
            if w.job_id is not None and self.on_worker_death:
                self.on_worker_death(self.jobs[w.job_id])


class LocalExecutor:
    """Worker processes on this machine (the default): ``run_jobs`` with ``workers``
    processes; ``in_process`` runs in this process when workers <= 1 (not for Blender).
    gpus: GPU indices handed to the processes in turn (run_jobs)."""

    name = "local"

    def __init__(self, workers: int = 1, retries: int = 1, recycle_after: int = 0, gpus=()):
        self.workers = workers
        self.retries = retries
        self.recycle_after = recycle_after
        self.gpus = tuple(gpus)

    def run(self, fn, jobs, *, in_process=True, on_progress=None, on_outcome=None, on_worker_death=None,
            parent_works=False):
        """parent_works (with in_process): this process is one of the workers (run_jobs)."""
        workers = 0 if (in_process and self.workers <= 1) else max(1, self.workers)
        return run_jobs(fn, jobs, workers=workers, retries=self.retries, recycle_after=self.recycle_after,
                        on_progress=on_progress, on_outcome=on_outcome, on_worker_death=on_worker_death,
                        parent_works=parent_works and in_process, gpus=self.gpus)

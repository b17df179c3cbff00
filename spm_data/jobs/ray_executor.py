"""Run shard jobs as Ray tasks (``--executor ray``): one task per shard.

A task runs the same job function as a local worker (render, occlude, import,
merge, feature extraction), so it writes its shard through the same atomic
writer into the output folder, which must be a path every node sees (a shared
filesystem; docs/scaling.md). Only the small result (manifest entry, counts)
comes back; the driver writes the manifest.

- Retries: a task whose worker process dies (killed, out of memory, a crashed
  renderer) is retried by Ray up to ``retries`` times; a job that raises is not
  retried (it would fail the same way) and is reported with its message; the
  other jobs go on.
- Recycling: ``recycle_after`` > 0 makes each Ray worker process exit after that
  many tasks (Ray's ``max_calls``), so a Blender that leaks is replaced.
- Resources: each task asks for ``task_cpus`` CPUs, so a node runs at most
  (its CPUs / task_cpus) tasks at once; give Blender tasks the CPUs Cycles'
  threads will use. ``task_gpus`` > 0 (render's --task-gpus; a fraction shares a
  GPU among tasks) also asks for GPUs, so render tasks run on GPU nodes, each on
  the GPU Ray gives it (base.GPU_VARIABLE); a cluster with no node that has that
  many GPUs is refused (its tasks would wait for ever).
- Without ``address``, a local Ray instance is started with ``workers`` CPUs,
  listening on loopback only, and stopped at the end; with one (``auto`` or
  ``HOST:PORT``), the run joins that cluster.
"""

from __future__ import annotations

import os
import sys

from spm_data.errors import SpmError
from spm_data.jobs.outcome import (JobOutcome, deferred_interrupt, error_text, is_blender_script_dir,
                                    warnings_as_lines)

INSTALL_HINT = "the Ray executor needs Ray: pip install 'spm[ray]' (or pip install ray)"


def _import_ray():
    # Before Ray is imported: a local instance then uses the loopback address for
    # every server, instead of the machine's network address.
    os.environ.setdefault("RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER", "0")
    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
    try:
        import ray
    except ImportError:
        raise SpmError(INSTALL_HINT) from None
    return ray


def _loopback_only() -> None:
    """Keep a local instance on 127.0.0.1 even when Ray was imported before us (the
    environment variable above is read at import): Ray decides whether "localhost"
    means the loopback address from this module constant, read at each call."""
    try:
        from ray._private import ray_constants
    except ImportError:  # a Ray without it: the environment variable is all we have
        return
    ray_constants.ENABLE_RAY_CLUSTER = False


def _ray_task(fn, job, gpu_variable=None):
    """Runs in a Ray worker: the job, its frame count and any error as a message.
    gpu_variable: with --task-gpus, where the renderer reads the GPU Ray gave the task."""
    sys.path[:] = [p for p in sys.path if not is_blender_script_dir(p)]
    warnings_as_lines()
    if gpu_variable:
        import ray

        ids = ray.get_gpu_ids()  # the node's GPU indices Ray gave this task (it sets CUDA_VISIBLE_DEVICES)
        if ids:
            os.environ[gpu_variable] = str(int(ids[0]))
    frames = [0]

    def report(n):
        frames[0] += n

    try:
        return {"result": fn(job, report), "frames": frames[0], "pid": os.getpid()}
    except Exception as exc:  # noqa: BLE001 - reported to the driver as the job's error
        return {"error": error_text(exc), "frames": frames[0], "pid": os.getpid()}


class RayExecutor:
    name = "ray"

    def __init__(self, *, address: str | None = None, workers: int = 1, task_cpus: float = 1.0,
                 retries: int = 1, recycle_after: int = 0, task_gpus: float = 0.0):
        self.address = address
        self.workers = workers
        self.task_cpus = task_cpus
        self.retries = retries
        self.recycle_after = recycle_after
        self.task_gpus = float(task_gpus)

    def with_task_gpus(self, task_gpus: float) -> "RayExecutor":
        """This executor with each task asking for ``task_gpus`` GPUs (render's --task-gpus)."""
        return RayExecutor(address=self.address, workers=self.workers, task_cpus=self.task_cpus,
                           retries=self.retries, recycle_after=self.recycle_after, task_gpus=task_gpus)

    def _connect(self, ray) -> bool:
        """Connect (or start a local instance); True when this call started it."""
        if ray.is_initialized():
            return False
        options = {"include_dashboard": False, "log_to_driver": False, "configure_logging": False}
        try:
            if self.address:
                ray.init(address=self.address, **options)
            else:
                _loopback_only()
                ray.init(num_cpus=max(1, int(self.workers)), **options)
        except Exception as exc:  # noqa: BLE001 - Ray raises many kinds; the user needs one line
            where = self.address or "a local instance"
            raise SpmError(f"cannot start Ray on {where}: {type(exc).__name__}: {exc}") from None
        return True

    def run(self, fn, jobs, *, in_process=True, on_progress=None, on_outcome=None, on_worker_death=None,
            parent_works=False):
        """parent_works: ignored (every job is a Ray task)."""
        ray = _import_ray()
        jobs = list(jobs)
        outcomes: list[JobOutcome | None] = [None] * len(jobs)
        if not jobs:
            return outcomes
        started = self._connect(ray)
        options = {"num_cpus": self.task_cpus, "max_retries": self.retries, "retry_exceptions": False}
        if self.recycle_after:
            options["max_calls"] = self.recycle_after
        gpu_variable = None
        if self.task_gpus:
            from spm_data.render.base import GPU_VARIABLE

            options["num_gpus"], gpu_variable = self.task_gpus, GPU_VARIABLE
        task = ray.remote(**options)(_ray_task)
        pending = {}
        try:
            if self.task_gpus:
                check_task_gpus(self.task_gpus, [n.get("Resources", {}).get("GPU", 0.0) for n in ray.nodes()
                                                 if n.get("Alive")])
            with deferred_interrupt() as stop:
                fn_ref = ray.put(fn)
                pending = {task.remote(fn_ref, job, gpu_variable): i for i, job in enumerate(jobs)}
                while pending:
                    if stop.is_set():
                        raise KeyboardInterrupt
                    done, _ = ray.wait(list(pending), num_returns=len(pending), timeout=0.2)
                    for ref in done:
                        i = pending.pop(ref)
                        try:
                            value = ray.get(ref)
                        except Exception as exc:  # noqa: BLE001 - the worker died more often than retried
                            if on_worker_death:
                                on_worker_death(jobs[i])
                            value = {"error": f"task failed after {self.retries + 1} attempts "
                                              f"({type(exc).__name__}: {str(exc).splitlines()[0][:200]})"}
                        outcomes[i] = JobOutcome(jobs[i], result=value.get("result"), error=value.get("error"))
                        if on_progress and value.get("frames"):
                            on_progress(value["frames"])
                        if on_outcome:
                            on_outcome(outcomes[i])
        finally:
            for ref in pending:
                ray.cancel(ref, force=True)
            for i in pending.values():
                if on_worker_death:
                    on_worker_death(jobs[i])
            if started:
                ray.shutdown()
        return outcomes


def check_task_gpus(task_gpus: float, node_gpus: list) -> None:
    """SpmError (one line) when no node has ``task_gpus`` GPUs (``node_gpus``: each live node's
    GPU count), where Ray would keep the tasks waiting for ever."""
    if not node_gpus or max(node_gpus) < task_gpus:
        most = max(node_gpus, default=0)
        have = "no GPUs" if not most else f"at most {most:g} GPU{'s' if most != 1 else ''} on a node"
        raise SpmError(f"--task-gpus {task_gpus:g}: the Ray cluster has {have}, so no render task could start; "
                       "start its GPU nodes with GPUs (ray start --num-gpus N) or ask for fewer")

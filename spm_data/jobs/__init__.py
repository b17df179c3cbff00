"""Running shard-sized jobs: local worker processes, Ray, and the resumable run of a folder.

Library functions take one ``executor`` (an object with ``run(fn, jobs, ...)``);
the CLI alone builds it from ``--workers``, ``--recycle-after``, ``--executor``,
``--address`` and ``--task-cpus`` with :func:`make_executor`.
"""

from __future__ import annotations

from spm_data.errors import SpmError


def make_executor(name: str = "local", *, workers: int = 1, address: str | None = None,
                  task_cpus: float = 1.0, retries: int = 1, recycle_after: int = 0):
    """``local`` (processes here) or ``ray`` (spm_data.jobs.ray_executor; needs the ``ray`` extra)."""
    if name == "local":
        from spm_data.jobs.executor import LocalExecutor

        return LocalExecutor(workers=workers, retries=retries, recycle_after=recycle_after)
    if name == "ray":
        from spm_data.jobs.ray_executor import RayExecutor

        return RayExecutor(address=address, workers=workers, task_cpus=task_cpus, retries=retries,
                           recycle_after=recycle_after)
    raise SpmError(f"executor must be 'local' or 'ray', got {name!r}")

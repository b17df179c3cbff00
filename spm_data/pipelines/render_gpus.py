"""The executor a render run gets for its GPUs: the render command's --gpus and --task-gpus,
checked against the GPUs the renderers list and the specs' own device settings."""

from __future__ import annotations

import warnings

from spm_data.errors import RenderError, SpmError, SpmWarning
from spm_data.jobs.executor import LocalExecutor
from spm_data.render.base import choose_gpus, contexts_per_gpu, gl_processes, parse_gpus, visible_gpus


def render_executor(executor, gpus, task_gpus: float, specs):
    """use_gpus for the RenderSpecs ``specs``; RenderError (one line) for --gpus with a spec that
    Blender renders on the CPU (``render.blender.device = "cpu"``): that spec would ignore it."""
    if gpus is not None:
        on_cpu = [s.class_name for s in specs if s.render.renderer == "blender"
                  and s.render.blender.engine == "cycles" and s.render.blender.device == "cpu"]
        if on_cpu:
            raise RenderError(f"--gpus {gpus}: {on_cpu[0]}'s spec renders on the CPU with Blender's Cycles "
                              '(render.blender.device = "cpu"); set device = "gpu" there, or leave --gpus out')
    return use_gpus(executor, gpus, task_gpus, {s.render.renderer for s in specs})


def use_gpus(executor, gpus, task_gpus: float, renderers):
    """The render run's ``executor`` with GPUs (the render command's --gpus and --task-gpus):
    Ray tasks ask for ``task_gpus`` each (RayExecutor.with_task_gpus); local workers get the
    GPUs ``gpus`` names ("0,1"; None: every GPU the ``renderers`` list here) in turn, in at
    most contexts_per_gpu() processes a GPU for a renderer that lists its GPUs here (pyrender:
    one GL context a process). RenderError / SpmError (one line) for a refusal."""
    wanted = parse_gpus(gpus)
    if executor.name != "local":
        if wanted is not None:
            raise SpmError("--gpus picks this machine's GPUs (--executor local); Ray tasks ask for theirs "
                           "with --task-gpus")
        return executor.with_task_gpus(task_gpus) if task_gpus else executor
    if task_gpus:
        raise SpmError("--task-gpus is for --executor ray; on this machine, pick GPUs with --gpus")
    per_gpu = contexts_per_gpu()   # a wrong $SPM_CONTEXTS_PER_GPU is refused here, with or without a GPU
    if wanted is None and executor.workers <= 1:
        return executor  # one worker: the renderer takes the first GPU itself
    listed = [found for found in (visible_gpus(r) for r in sorted(set(renderers))) if found is not None]
    if not listed:  # Blender alone lists its GPUs in its workers, which check the indices
        return LocalExecutor(executor.workers, executor.retries, executor.recycle_after, wanted or ())
    chosen = choose_gpus(wanted, *listed[0])
    processes = gl_processes(executor.workers, len(chosen), per_gpu)
    if processes < len(chosen):
        warnings.warn(f"--workers {executor.workers} renders on {processes} of the {len(chosen)} GPUs; give "
                      f"--workers {len(chosen)} or more to use them all", SpmWarning)
    return LocalExecutor(processes, executor.retries, executor.recycle_after, chosen)

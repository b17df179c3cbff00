"""spm_data.pipelines.render_gpus: the executor of a render run for its GPUs: local workers spread
over the GPUs the renderers list in few GL contexts a GPU, Ray tasks asking for theirs, and every
refusal in one line (tested without a GPU: pyrender's device list is injected)."""

import pytest

from spm_data.pipelines.render_gpus import render_executor, use_gpus
from spm_data.errors import RenderError, SpmError, SpmWarning


def fake_visible(monkeypatch, gpus):
    from spm_data.render import pyrender_backend

    monkeypatch.setattr(pyrender_backend, "visible_gpus", lambda: (tuple(gpus), "pyrender's EGL"))


def test_use_gpus_spreads_workers_over_few_gl_contexts_a_gpu(monkeypatch):
    from spm_data.jobs.executor import LocalExecutor

    fake_visible(monkeypatch, (0, 1, 2))
    local = LocalExecutor(workers=8, retries=2, recycle_after=16)
    on_all = use_gpus(local, None, 0.0, {"pyrender"})
    assert (on_all.gpus, on_all.workers, on_all.retries, on_all.recycle_after) == ((0, 1, 2), 8, 2, 16)
    one = use_gpus(local, "2", 0.0, {"pyrender"})
    assert (one.gpus, one.workers) == ((2,), 4)      # 8-way work in 4 GL contexts on GPU 2
    assert use_gpus(LocalExecutor(workers=1), None, 0.0, {"pyrender"}).gpus == ()  # one worker: the first GPU
    blender = use_gpus(local, "0,1", 0.0, {"blender"})   # Blender checks indices in its workers
    assert (blender.gpus, blender.workers) == ((0, 1), 8)
    with pytest.warns(SpmWarning, match=r"^--workers 1 renders on 1 of the 3 GPUs; give --workers 3 or more to use "
                                        r"them all$"):
        assert use_gpus(LocalExecutor(workers=1), "0,1,2", 0.0, {"pyrender"}).gpus == (0, 1, 2)
    fake_visible(monkeypatch, ())
    cpu = use_gpus(LocalExecutor(workers=4), None, 0.0, {"pyrender"})
    assert (cpu.gpus, cpu.workers) == ((), 4)        # no GPU: one llvmpipe process per worker


def test_use_gpus_refusals_are_one_line(monkeypatch):
    from spm_data.errors import RenderError
    from spm_data.jobs.executor import LocalExecutor
    from spm_data.jobs.ray_executor import RayExecutor

    fake_visible(monkeypatch, (0, 1))
    with pytest.raises(RenderError, match=r"^--gpus 0,2: there is no GPU 2; pyrender's EGL lists 2: 0, 1$"):
        use_gpus(LocalExecutor(workers=2), "0,2", 0.0, {"pyrender"})
    with pytest.raises(RenderError, match=r"^--gpus 'x': expected GPU indices"):
        use_gpus(LocalExecutor(workers=2), "x", 0.0, {"pyrender"})
    with pytest.raises(SpmError, match=r"^--task-gpus is for --executor ray; on this machine, pick GPUs with --gpus$"):
        use_gpus(LocalExecutor(), None, 1.0, {"pyrender"})
    with pytest.raises(SpmError, match=r"^--gpus picks this machine's GPUs \(--executor local\); Ray tasks ask for "
                                       r"theirs with --task-gpus$"):
        use_gpus(RayExecutor(), "0", 0.0, {"pyrender"})
    assert use_gpus(RayExecutor(task_cpus=2), None, 0.5, {"pyrender"}).task_gpus == 0.5
    fake_visible(monkeypatch, ())
    with pytest.raises(RenderError, match=r"^--gpus 0: no GPU here \(pyrender's EGL lists none\); leave --gpus out "
                                          r"to render on the CPU$"):
        use_gpus(LocalExecutor(), "0", 0.0, {"pyrender"})


def test_a_bad_contexts_per_gpu_is_refused_with_or_without_a_gpu(monkeypatch):
    from spm_data.jobs.executor import LocalExecutor

    monkeypatch.setenv("SPM_CONTEXTS_PER_GPU", "0")
    for gpus in ((), (0,)):
        fake_visible(monkeypatch, gpus)
        with pytest.raises(RenderError, match=r"^SPM_CONTEXTS_PER_GPU='0': expected a whole number"):
            use_gpus(LocalExecutor(workers=2), None, 0.0, {"pyrender"})
    monkeypatch.setenv("SPM_CONTEXTS_PER_GPU", "1")
    assert use_gpus(LocalExecutor(workers=8), None, 0.0, {"pyrender"}).workers == 1   # one GPU, one context


def test_gpus_for_a_spec_that_cycles_renders_on_the_cpu_is_refused(monkeypatch):
    from spm_data.core.specs import parse_spec
    from spm_data.jobs.executor import LocalExecutor

    text = 'class = "cup"\n[render]\nrenderer = "blender"\n[render.blender]\nengine = "{}"\ndevice = "{}"\n'
    on_cpu, on_gpu, workbench = (parse_spec(text.format(e, d), "test") for e, d in
                                 (("cycles", "cpu"), ("cycles", "gpu"), ("workbench", "cpu")))
    with pytest.raises(RenderError, match=r'^--gpus 0: cup\'s spec renders on the CPU with Blender\'s Cycles '
                                          r'\(render.blender.device = "cpu"\); set device = "gpu" there, or leave '
                                          r'--gpus out$'):
        render_executor(LocalExecutor(workers=2), "0", 0.0, [on_cpu])
    assert render_executor(LocalExecutor(workers=2), None, 0.0, [on_cpu]).workers == 2   # no --gpus: as the spec says
    for spec in (on_gpu, workbench):   # Blender checks the indices in its workers
        assert render_executor(LocalExecutor(workers=2), "0", 0.0, [spec]).gpus == (0,)

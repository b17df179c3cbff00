"""spm_data.jobs.make_executor: the executor the CLI builds from its options."""

import pytest

from spm_data.errors import SpmError
from spm_data.jobs import make_executor


def test_ray_executor_without_ray_says_how_to_install_it(monkeypatch):
    import sys

    from spm_data.errors import SpmError
    from spm_data.jobs import make_executor

    monkeypatch.setitem(sys.modules, "ray", None)  # as if not installed: import ray raises ImportError
    with pytest.raises(SpmError, match=r"pip install 'spm\[ray\]'"):
        make_executor("ray").run(len, [1])


def test_unknown_executor_is_a_one_line_error():
    with pytest.raises(SpmError, match="executor must be 'local' or 'ray'"):
        make_executor("slurm")


def test_the_options_reach_the_executor():
    from spm_data.jobs.executor import LocalExecutor
    from spm_data.jobs.ray_executor import RayExecutor

    local = make_executor(workers=3, retries=2, recycle_after=5)
    assert isinstance(local, LocalExecutor) and local.name == "local"
    assert (local.workers, local.retries, local.recycle_after) == (3, 2, 5)
    ray = make_executor("ray", workers=4, address="auto", task_cpus=2.5, retries=0, recycle_after=1)
    assert isinstance(ray, RayExecutor)     # built without importing ray: that happens when it runs
    assert (ray.address, ray.workers, ray.task_cpus, ray.retries, ray.recycle_after) == ("auto", 4, 2.5, 0, 1)

"""The Ray executor: same arrays as the local pool, and a killed task is retried.

A local Ray instance with 2 CPUs, listening on loopback only, is started by the
executor itself (spm_data/jobs/ray_executor.py)."""

import os
import signal
import threading
import time
from pathlib import Path

import numpy as np
import pytest

ray = pytest.importorskip("ray")

from tests.helpers import write_pyrender_128_spec  # noqa: E402
from spm_data.jobs import make_executor  # noqa: E402
from spm_data.pipelines.occlude_jobs import occlude_dataset  # noqa: E402
from spm_data.pipelines.render_jobs import load_run_specs, render_dataset  # noqa: E402
from spm_data.io.shards import list_shards, read_manifest, read_shard  # noqa: E402

pytestmark = pytest.mark.slow  # starts a local Ray cluster

@pytest.fixture
def specs(tmp_path):
    folder = tmp_path / "specs"
    folder.mkdir()
    for cls in ("cup", "car"):
        write_pyrender_128_spec(folder, cls, seed=2, az_stop=95, el=10, per_shard=20)
    return load_run_specs(all_classes=True, specs_dir=folder)


def assert_same_arrays(a: Path, b: Path):
    sa, sb = list_shards(a), list_shards(b)
    assert [p.name for p in sa] == [p.name for p in sb] and sa
    for pa, pb in zip(sa, sb):
        da, db = read_shard(pa), read_shard(pb)
        assert sorted(da) == sorted(db)
        for k in da:
            assert np.array_equal(da[k], db[k]), f"{pa.name}:{k}"


def test_ray_renders_and_occludes_the_same_arrays_as_local_processes(specs, tmp_path):
    ray_exec = make_executor("ray", workers=2)
    local = render_dataset(specs, tmp_path / "local")
    remote = render_dataset(specs, tmp_path / "ray", executor=ray_exec)
    assert remote.failed == [] and remote.frames == local.frames == 80 and len(remote.done) == 4
    assert_same_arrays(tmp_path / "local", tmp_path / "ray")
    assert [e["sha256"] for e in read_manifest(tmp_path / "ray")["shards"]] == \
           [e["sha256"] for e in read_manifest(tmp_path / "local")["shards"]]
    occlude_dataset(tmp_path / "local", tmp_path / "local_occ", high=0.5, seed=4)
    occlude_dataset(tmp_path / "ray", tmp_path / "ray_occ", high=0.5, seed=4, executor=ray_exec)
    assert_same_arrays(tmp_path / "local_occ", tmp_path / "ray_occ")
    assert not ray.is_initialized()  # the local instance it started is stopped


def _kill_first_running_task(found: list, stop: threading.Event):
    """SIGKILL the first Ray worker seen running a task (its title is ray::_ray_task)."""
    while not stop.is_set() and not found:
        for pid in os.listdir("/proc"):
            if not pid.isdigit():
                continue
            try:
                cmdline = Path(f"/proc/{pid}/cmdline").read_bytes()
            except OSError:
                continue
            if cmdline.startswith(b"ray::_ray_task"):
                os.kill(int(pid), signal.SIGKILL)
                found.append(int(pid))
                return
        time.sleep(0.002)


def test_a_killed_task_is_retried_and_the_run_completes(specs, tmp_path):
    render_dataset(specs, tmp_path / "local")
    found, stop = [], threading.Event()
    killer = threading.Thread(target=_kill_first_running_task, args=(found, stop), daemon=True)
    killer.start()
    try:
        summary = render_dataset(specs, tmp_path / "ray", executor=make_executor("ray", workers=2, retries=2))
    finally:
        stop.set()
        killer.join()
    assert found, "no running Ray task was seen to kill"
    assert summary.failed == [] and len(summary.done) == 4 and summary.complete == 4
    assert not list((tmp_path / "ray").glob(".*.partial"))
    assert_same_arrays(tmp_path / "local", tmp_path / "ray")


def test_features_on_ray_equal_local_and_a_failing_job_is_reported(specs, tmp_path):
    from spm_model.bench.feature_cache import extract_shard, load_features
    from spm_model.spm.features import FeatureConfig

    render_dataset(specs, tmp_path / "shards")
    config = FeatureConfig(ellipse="direct")
    shards = list_shards(tmp_path / "shards")
    jobs = [(str(shards[0]), config), (str(tmp_path / "missing.h5"), config), (str(shards[1]), config)]
    outcomes = make_executor("ray", workers=2).run(extract_shard, jobs)
    assert outcomes[0].error is None and outcomes[2].error is None
    assert "shard not found" in outcomes[1].error and outcomes[1].result is None
    # Feature extraction for `spm train` on Ray: the same cached arrays as in this process.
    cached = {p: np.load(p) for p in (outcomes[0].result, outcomes[2].result)}
    local = load_features(tmp_path / "shards", config)               # reuses the two Ray-made cache files...
    for p in cached:
        Path(p).unlink()
    again = load_features(tmp_path / "shards", config)               # ...and recomputes them here
    for k in ("train_vector", "query_vector", "raw", "pose"):
        assert np.array_equal(local.arrays[k], again.arrays[k], equal_nan=True), k


def test_recycle_after_replaces_ray_worker_processes():
    from spm_data.jobs.outcome import probe_job

    recycled = make_executor("ray", workers=1, recycle_after=2).run(probe_job, list(range(6)))
    pids = [o.result["pid"] for o in recycled]
    assert [o.result["job"] for o in recycled] == list(range(6))
    assert len(set(pids)) >= 3                      # at most 2 jobs per worker process
    assert all(pids.count(p) <= 2 for p in pids)


def test_the_local_instance_listens_on_loopback_only():
    from spm_data.jobs.ray_executor import RayExecutor

    executor = RayExecutor(workers=2)
    assert executor._connect(ray)          # started here, although ray was imported first
    try:
        assert ray.cluster_resources()["CPU"] == 2
        assert [n["NodeManagerAddress"] for n in ray.nodes()] == ["127.0.0.1"]
        assert ray.get_runtime_context().gcs_address.startswith("127.0.0.1:")
    finally:
        ray.shutdown()


def test_cli_occlude_with_the_ray_executor(specs, tmp_path):
    from click.testing import CliRunner

    from cli import data_cli

    render_dataset(specs, tmp_path / "in")
    runner = CliRunner()
    args = ["occlude", str(tmp_path / "in"), "--max", "0.4", "--workers", "2"]
    r = runner.invoke(data_cli, args + ["--out", str(tmp_path / "ray"), "--executor", "ray"])
    assert r.exit_code == 0, r.output
    assert "occluded 4 shards (80 frames)" in r.output and "0 failed" in r.output
    r = runner.invoke(data_cli, args + ["--out", str(tmp_path / "local")])
    assert r.exit_code == 0, r.output
    assert_same_arrays(tmp_path / "local", tmp_path / "ray")


def test_ray_renders_a_randomised_cluttered_spec_to_the_same_bytes(tmp_path):
    from tests.pipelines.test_render_frames import CLUTTERED

    folder = tmp_path / "specs"
    folder.mkdir()
    (folder / "c.toml").write_text(CLUTTERED.format(cls="c"))
    specs = load_run_specs(all_classes=True, specs_dir=folder)
    render_dataset(specs, tmp_path / "local", limit=16)
    remote = render_dataset(specs, tmp_path / "ray", limit=16, executor=make_executor("ray", workers=2))
    assert remote.failed == [] and remote.frames == 16
    assert [e["sha256"] for e in read_manifest(tmp_path / "ray")["shards"]] == \
           [e["sha256"] for e in read_manifest(tmp_path / "local")["shards"]]


def test_task_gpus_are_refused_where_no_node_has_them():
    from spm_data.errors import SpmError
    from spm_data.jobs.ray_executor import check_task_gpus

    check_task_gpus(1, [0.0, 2.0])
    check_task_gpus(0.25, [1.0])
    with pytest.raises(SpmError, match=r"^--task-gpus 1: the Ray cluster has no GPUs, so no render task could start; "
                                       r"start its GPU nodes with GPUs \(ray start --num-gpus N\) or ask for fewer$"):
        check_task_gpus(1, [0.0, 0.0])
    with pytest.raises(SpmError, match=r"^--task-gpus 2: the Ray cluster has at most 1 GPU on a node"):
        check_task_gpus(2, [1.0])
    # This machine's local instance has no GPU: refused at once, not left waiting.
    with pytest.raises(SpmError, match=r"^--task-gpus 1: the Ray cluster has no GPUs"):
        make_executor("ray", workers=1).with_task_gpus(1).run(lambda job, report: job, [1])
    assert not ray.is_initialized()


def test_a_task_renders_on_the_gpu_ray_gave_it(monkeypatch):
    from spm_data.jobs.ray_executor import _ray_task
    from spm_data.render.base import GPU_VARIABLE

    monkeypatch.setattr(ray, "get_gpu_ids", lambda: [3])
    monkeypatch.setenv(GPU_VARIABLE, "")  # recorded as it is, so the test leaves it so
    monkeypatch.delenv(GPU_VARIABLE)
    got = _ray_task(lambda job, report: os.environ.get(GPU_VARIABLE), "job", GPU_VARIABLE)
    assert got["result"] == "3"
    monkeypatch.delenv(GPU_VARIABLE)
    assert _ray_task(lambda job, report: os.environ.get(GPU_VARIABLE), "job")["result"] is None  # no --task-gpus

"""Executors compared: frames per second with 1 and 2 workers for the local process
pool and Ray, per renderer, and each executor's overhead per shard.

    python benchmarks/executor_scaling.py [--frames 1024] [--blender-frames 256]

Overhead per shard: the wall time of running no-op shard jobs through the
executor with one worker, per job, against the time one 256-frame pyrender
shard (128x128) takes to render and write in this process (target: < 5%).
Frames per second include starting the workers (and, for Ray, a local Ray
instance), as a user's run does.

Progress on stderr (a bar on a terminal, a line every $SPM_PROGRESS_EVERY s, default 10, elsewhere).
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from spm_data.jobs.progress import stage  # noqa: E402
from spm_data.jobs import make_executor  # noqa: E402
from spm_data.jobs.outcome import probe_job  # noqa: E402
from spm_data.core.paths import AngleRange  # noqa: E402
from spm_data.pipelines.render_jobs import load_run_specs, plan_shards, render_dataset, render_shard  # noqa: E402


def spec_for(renderer: str, frames: int, per_shard: int):
    spec = load_run_specs(["cup"])[0]
    views = -(-frames // 12)  # 12 elevations (0-55); enough azimuths for the frames
    spec = replace(spec, camera=replace(spec.camera, azimuth=AngleRange(0, 5 * (views - 1), 5),
                                        elevation=AngleRange(0, 55, 5)),
                   mesh=replace(spec.mesh, instances=1),
                   render=replace(spec.render, renderer=renderer, frames_per_shard=per_shard))
    if renderer == "blender":
        spec = replace(spec, render=replace(spec.render, blender=replace(spec.render.blender, samples=8)))
    return spec


def shard_seconds(tmp: Path) -> float:
    spec = spec_for("pyrender", 512, 256)
    jobs = plan_shards(spec, tmp / "one", limit=512)
    (tmp / "one").mkdir()
    render_shard(jobs[0])  # warm up the renderer
    started = time.perf_counter()
    render_shard(jobs[1])
    return time.perf_counter() - started


def overhead_per_job(name: str, jobs: int = 64) -> float:
    executor = make_executor(name, workers=1)
    executor.run(probe_job, list(range(4)), in_process=False)  # start-up, not counted
    if name == "ray":
        import ray

        ray.init(num_cpus=1, include_dashboard=False, log_to_driver=False, configure_logging=False)
        try:
            executor.run(probe_job, list(range(4)))  # warm workers
            started = time.perf_counter()
            executor.run(probe_job, list(range(jobs)))
            return (time.perf_counter() - started) / jobs
        finally:
            ray.shutdown()
    started = time.perf_counter()
    executor.run(probe_job, list(range(jobs)), in_process=False)
    return (time.perf_counter() - started) / jobs


def fps(renderer: str, executor: str, workers: int, frames: int, per_shard: int, tmp: Path) -> float:
    out = tmp / f"{renderer}-{executor}-{workers}"
    spec = spec_for(renderer, frames, per_shard)
    started = time.perf_counter()
    with stage(f"executor_scaling: {frames} {renderer} frames, {executor} executor, {workers} workers",
               unit="frame") as progress:
        summary = render_dataset([spec], out, limit=frames, executor=make_executor(executor, workers=workers),
                                 progress=progress)
    assert not summary.failed, summary.failed
    return summary.frames / (time.perf_counter() - started)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=1024, help="pyrender frames per run")
    parser.add_argument("--blender-frames", type=int, default=256, help="Blender Cycles (8 samples) frames per run")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        with stage("executor_scaling: one 256-frame pyrender shard, in process"):
            shard = shard_seconds(tmp)
        print(f"one 256-frame pyrender shard, in process: {shard:.2f} s")
        for name in ("local", "ray"):
            with stage(f"executor_scaling: {name} executor, 64 no-op shard jobs"):
                per_job = overhead_per_job(name)
            print(f"{name}: overhead per shard job {1000 * per_job:.1f} ms = {100 * per_job / shard:.2f}% of a shard")
        print("\n| renderer | executor | workers | frames | frames/s |\n|---|---|---|---|---|")
        for renderer, frames, per_shard in (("pyrender", args.frames, 256), ("blender", args.blender_frames, 64)):
            for executor in ("local", "ray"):
                for workers in (1, 2):
                    rate = fps(renderer, executor, workers, frames, per_shard, tmp)
                    print(f"| {renderer} | {executor} | {workers} | {frames} | {rate:.1f} |", flush=True)


if __name__ == "__main__":
    main()

"""Render throughput: frames per second, and the share of time spent outside rendering.

For each resolution it times (1) a bare loop of renderer.render over the
frames and (2) the whole `spm-data render` path for the same frames
(path generation, meshes, compositing, HDF5 shard writing, manifest), in one
process, and prints fps for both and the overhead = 1 - bare / whole.
Target: overhead under 10%. Writing costs about 1 ms a frame at 256x256 (LZF
compression inside HDF5, which holds the GIL, so a writer thread does not help).
"""

import argparse
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from spm_data.paths import camera_path  # noqa: E402
from spm_data.render import make_renderer  # noqa: E402
from spm_data.render_jobs import load_instance, plan_shards, render_dataset  # noqa: E402
from spm_data.specs import find_spec, load_spec  # noqa: E402


def bench(spec, frames: int, renderer_name: str, repeats: int = 3) -> tuple[float, float]:
    """Best-of-``repeats`` seconds for the bare loop and the whole path, interleaved
    so that load from other users of a shared machine hits both alike."""
    runs = [_bench_once(spec, frames, renderer_name) for _ in range(repeats)]
    return min(r[0] for r in runs), min(r[1] for r in runs)


def _bench_once(spec, frames: int, renderer_name: str) -> tuple[float, float]:
    jobs = plan_shards(spec, "unused", limit=frames)
    path = camera_path(spec.camera)
    poses = [path.poses(job.path_indices) for job in jobs]  # outside the timed loop
    renderer = make_renderer(spec, renderer_name)
    # Warm up: GL context, shader compilation, mesh building (cached for both loops).
    for inst in sorted({int(i) for j in jobs for i in j.instances}):
        renderer.set_mesh(load_instance(spec, inst))
        renderer.render(poses[0][0][0], poses[0][1][0])
    started = time.perf_counter()
    for job, (R, t) in zip(jobs, poses):
        current = None
        for k, inst in enumerate(job.instances):
            if inst != current:
                renderer.set_mesh(load_instance(spec, int(inst)))
                current = inst
            renderer.render(R[k], t[k])
    bare = time.perf_counter() - started
    with tempfile.TemporaryDirectory() as out:
        started = time.perf_counter()
        summary = render_dataset([spec], out, limit=frames, workers=1)
        whole = time.perf_counter() - started
    assert summary.frames == frames
    return bare, whole


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=512)
    parser.add_argument("--class", dest="cls", default="cup")
    args = parser.parse_args()
    base = load_spec(find_spec(args.cls))
    print(f"class {args.cls}, {args.frames} frames, 1 process, best of 3 interleaved runs")
    print("| renderer | size | bare render fps | spm-data render fps | overhead |")
    print("|---|---|---|---|---|")
    for size in (128, 256):
        spec = base.replace(image=type(base.image)(width=size, height=size, fov=base.image.fov))
        bare, whole = bench(spec, args.frames, "pyrender")
        print(f"| pyrender | {size}x{size} | {args.frames / bare:.0f} | {args.frames / whole:.0f} | "
              f"{100 * (1 - bare / whole):.1f}% |")


if __name__ == "__main__":
    main()

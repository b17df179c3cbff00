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
from dataclasses import replace
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from spm_data.core.paths import camera_path  # noqa: E402
from spm_data.render import make_renderer  # noqa: E402
from spm_data.core.instances import load_instance  # noqa: E402
from spm_data.commands.render_jobs import plan_shards, render_dataset  # noqa: E402
from spm_data.core.specs import find_spec, load_spec  # noqa: E402
from spm_data.jobs.executor import LocalExecutor  # noqa: E402


def bench(spec, frames: int, renderer_name: str, repeats: int = 3) -> tuple[float, float]:
    """Best-of-``repeats`` seconds for the bare loop and the whole path, interleaved
    so that load from other users of a shared machine hits both alike."""
    runs = [_bench_once(spec, frames, renderer_name) for _ in range(repeats)]
    return min(r[0] for r in runs), min(r[1] for r in runs)


def _bench_once(spec, frames: int, renderer_name: str) -> tuple[float, float]:
    jobs = plan_shards(spec, "unused", limit=frames)
    path = camera_path(spec.camera, spec.seed)
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
        summary = render_dataset([spec], out, limit=frames)
        whole = time.perf_counter() - started
    assert summary.frames == frames
    return bare, whole


def bench_blender(base, engine: str, samples: int, frames: int) -> dict:
    """Blender at 128x128: in-process per-frame times against a bare render loop, and
    whole `spm-data render` runs with 1 and 2 worker processes."""
    import bpy

    blender = replace(base.render.blender, engine=engine, samples=samples)
    spec = base.replace(render=replace(base.render, renderer="blender", blender=blender,
                                       frames_per_shard=max(1, frames // 4)))
    jobs = plan_shards(spec, "unused", limit=frames)
    path = camera_path(spec.camera, spec.seed)
    R, t = path.poses(jobs[0].path_indices)
    renderer = make_renderer(spec, "blender")
    renderer.set_mesh(load_instance(spec, int(jobs[0].instances[0])))
    renderer.render(R[0], t[0])  # warm-up (kernels, BVH)
    n = len(R)

    def bare_loop():
        from spm_data.core.poses import cv_to_gl_camera_to_world
        import mathutils

        started = time.perf_counter()
        for k in range(n):
            renderer._camera.matrix_world = mathutils.Matrix(cv_to_gl_camera_to_world(R[k], t[k]).tolist())
            bpy.ops.render.render()
        return (time.perf_counter() - started) / n

    def our_loop():
        started = time.perf_counter()
        for k in range(n):
            renderer.render(R[k], t[k])
        return (time.perf_counter() - started) / n

    bare = min(bare_loop(), bare_loop())
    ours = min(our_loop(), our_loop())
    renderer.close()
    result = {"bare_ms": 1000 * bare, "ours_ms": 1000 * ours}
    for workers in (1, 2):
        with tempfile.TemporaryDirectory() as out:
            summary = render_dataset([spec], out, limit=frames, executor=LocalExecutor(workers=workers))
            assert summary.frames == frames and not summary.failed, summary.report()
            result[f"fps_{workers}"] = frames / summary.seconds
    return result


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=512)
    parser.add_argument("--class", dest="cls", default="cup")
    parser.add_argument("--no-blender", action="store_true", help="pyrender only")
    args = parser.parse_args()
    base = load_spec(find_spec(args.cls))
    print(f"class {args.cls}, {args.frames} frames, 1 process, best of 3 interleaved runs")
    print("| renderer | size | bare render fps | spm-data render fps | overhead |")
    print("|---|---|---|---|---|")
    for size in (128, 256):
        spec = base.replace(image=type(base.image)(width=size, height=size, fov=base.image.fov),
                            render=replace(base.render, renderer="pyrender"))
        bare, whole = bench(spec, args.frames, "pyrender")
        print(f"| pyrender | {size}x{size} | {args.frames / bare:.0f} | {args.frames / whole:.0f} | "
              f"{100 * (1 - bare / whole):.1f}% |")
    if args.no_blender:
        return
    print("\nBlender 5.0 at 128x128 (per frame: bare = camera move + bpy.ops.render.render(); ours = "
          "renderer.render(), i.e. that plus the multi-layer EXR written and read back; runs include "
          "worker start-up, bpy import and shard writing)")
    print("| engine | frames | bare ms/frame | ours ms/frame | ours / bare | run fps, 1 worker | run fps, 2 workers |")
    print("|---|---|---|---|---|---|---|")
    for engine, samples, frames in (("cycles", 8, 256), ("cycles", 64, 64), ("workbench", 16, 256)):
        r = bench_blender(base, engine, samples, frames)
        label = f"Cycles {samples} samples" if engine == "cycles" else "Workbench"
        print(f"| {label} | {frames} | {r['bare_ms']:.1f} | {r['ours_ms']:.1f} | {r['ours_ms'] / r['bare_ms']:.2f} | "
              f"{r['fps_1']:.1f} | {r['fps_2']:.1f} |")


if __name__ == "__main__":
    main()

"""Render throughput: frames per second of a bare render loop and of the whole path, their ratio, and where the time
goes.

pyrender (per image size and worker count, best of --rounds interleaved runs): (1) a bare
loop of renderer.render over the frames, with the frames' own draws and distractors (made
before the loop), in each of N processes at once (their frames split as the shards are;
1 worker: this process) and (2) the whole `spm-data render` path for the same frames
(render_dataset with N local workers as `spm-data render --workers N` builds them: on GPUs
in at most $SPM_CONTEXTS_PER_GPU (default 4) render processes a GPU; path generation, meshes, draws, distractors,
compositing, compression, HDF5 shard writing, manifest; with N > 1 the workers' start-up is
included). Prints fps for both, whole / bare, and the split of the whole path: ms per frame
busy in each stage (render, readback, composite, compress, write; they overlap, and with
N workers they add up over the workers), and the GL renderer it ran on (GL_RENDERER:
llvmpipe on the CPU, the GPU's name on a GPU). --frames is per worker. Runs unchanged on a
GPU machine. Targets (issue 37, the 2-core CPU machine): whole / bare <= 1.10 at 128x128
and 256x256 in one process.

Blender (--blender-frames of each shipped spec, at the spec's settings, Cycles and
Workbench): bare = camera move + bpy.ops.render.render() and nothing else (no file
written: Blender's own cost for the frame); ours = Renderer.render; whole =
render_dataset with 1 and 2 worker processes; and, for the full set of shipped
specs, an extrapolation (whole s/frame x frames), not a measurement.
Targets: Cycles ours / bare <= 1.05 and the full set <= 12 min; Workbench ours / bare <= 1.3.
Progress on stderr (a bar on a terminal, a line every $SPM_PROGRESS_EVERY s, default 10, elsewhere).
"""

import argparse
import os
import resource
import sys
from dataclasses import replace
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from spm_data.jobs.progress import stage  # noqa: E402
from spm_data.core.paths import camera_path  # noqa: E402
from spm_data.render import make_renderer  # noqa: E402
from spm_data.core.instances import load_instance  # noqa: E402
from spm_data.pipelines.render_frames import FrameMaker  # noqa: E402
from spm_data.pipelines.render_jobs import RECYCLE_AFTER, plan_shards, render_dataset  # noqa: E402
from spm_data.core.specs import all_spec_paths, find_spec, load_spec  # noqa: E402
from spm_data.pipelines.render_gpus import use_gpus  # noqa: E402
from spm_data.jobs.executor import LocalExecutor, run_jobs  # noqa: E402

STAGES = ("render", "readback", "composite", "compress", "write")


class _FirstFrame:
    """render_dataset's progress: when the first frame was done (the workers' start-up over)."""

    total = None

    def __init__(self):
        self.first = None

    def __call__(self, n):
        if self.first is None:
            self.first = time.perf_counter()


def bench(spec, frames: int, workers: int, rounds: int = 3) -> dict:
    """Best-of-``rounds`` seconds of the bare loop, of the whole path and of the whole path
    from its first frame (``warm``: without the workers' start-up) over ``frames`` frames
    with ``workers`` processes, interleaved so that load from other users of a shared machine
    hits both alike; ``paired``: the median of each round's whole / bare; ``split``: the whole
    path's busy seconds per stage, of its best run."""
    size = f"{spec.image.width}x{spec.image.height}"
    best = {"bare": float("inf"), "whole": float("inf"), "warm": float("inf"), "split": {},
            "bare_cpu": float("inf"), "whole_cpu": float("inf")}
    ratios = []
    with stage(f"render_throughput: pyrender {size}, {workers} workers, bare loop and whole path, {frames} frames, "
               f"{rounds} rounds", 2 * frames * rounds, "frame") as progress:
        for _ in range(rounds):
            bare, bare_cpu = _bare(spec, frames, workers)
            best["bare"], best["bare_cpu"] = min(best["bare"], bare), min(best["bare_cpu"], bare_cpu)
            progress(frames)
            first = _FirstFrame()
            with tempfile.TemporaryDirectory() as out:
                # As `spm-data render --workers N` builds it: on GPUs, N-way work in fewer GL contexts.
                executor = use_gpus(LocalExecutor(workers=workers, retries=1, recycle_after=RECYCLE_AFTER), None,
                                    0.0, {"pyrender"})
                best["processes"] = executor.workers
                started, cpu = time.perf_counter(), _cpu_seconds()
                summary = render_dataset([spec], out, limit=frames, executor=executor, progress=first)
                ended = time.perf_counter()
                best["whole_cpu"] = min(best["whole_cpu"], _cpu_seconds() - cpu)
            assert summary.frames == frames and not summary.failed, summary.report()
            ratios.append((ended - started) / bare)
            # the first frame's own time
            best["warm"] = min(best["warm"], (ended - first.first) * frames / (frames - 1))
            if ended - started < best["whole"]:
                splits = [result.get("seconds", {}) for result in summary.results.values()]
                best["whole"], best["split"] = ended - started, {k: sum(s.get(k, 0.0) for s in splits) for k in STAGES}
            progress(frames)
    best["paired"] = sorted(ratios)[len(ratios) // 2]
    return best


def _cpu_seconds() -> float:
    """CPU seconds of this process (every thread) and of its finished worker processes: the
    work done, which other users of a shared machine slow down less than the wall-clock time."""
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    return time.process_time() + children.ru_utime + children.ru_stime


def _bare(spec, frames: int, workers: int) -> tuple[float, float]:
    """(seconds, CPU seconds) of the bare loop over the ``frames`` frames ``--limit`` picks: in
    this process for one worker, else in ``workers`` processes at once (from the moment all are
    ready; CPU summed over them)."""
    if workers <= 1:
        return _bare_loop((spec, frames, 1, 0, None))[1:3]
    with tempfile.TemporaryDirectory() as barrier:
        outcomes = run_jobs(_bare_loop, [(spec, frames, workers, i, barrier) for i in range(workers)],
                            workers=workers, retries=0)
    spans = [o.result for o in outcomes]
    assert all(o.error is None for o in outcomes), [o.error for o in outcomes]
    return max(s[3] for s in spans) - min(s[0] for s in spans), sum(s[2] for s in spans)


def _bare_loop(job, report=lambda n: None) -> tuple[float, float, float, float]:
    """(start, seconds, CPU seconds, end) of the bare loop over worker ``index``'s share of the
    shards (every ``workers``-th); with a ``barrier`` folder, started once every worker is ready
    (warm)."""
    spec, frames, workers, index, barrier = job
    jobs = [j for j in plan_shards(spec, "unused", limit=frames) if j.shard_index % workers == index]
    path = camera_path(spec.camera, spec.seed)
    poses = [path.poses(j.path_indices) for j in jobs]  # outside the timed loop
    renderer = make_renderer(spec, "pyrender")
    # Warm up: GL context, shader compilation, mesh building (cached for both loops).
    for inst in sorted({int(i) for j in jobs for i in j.instances}):
        renderer.set_mesh(load_instance(spec, inst))
        renderer.render(poses[0][0][0], poses[0][1][0])
    scenes = _scenes(spec, renderer, jobs, poses)  # outside the timed loop
    if barrier:
        Path(barrier, f"ready-{index}").touch()
        while len(list(Path(barrier).glob("ready-*"))) < workers:  # every worker warm: start together
            time.sleep(0.005)
    started, cpu, begin = time.perf_counter(), time.process_time(), time.time()
    for job, (R, t), scene in zip(jobs, poses, scenes):
        current = None
        for k, inst in enumerate(job.instances):
            if inst != current:
                renderer.set_mesh(load_instance(spec, int(inst)))
                current = inst
            draws, distractors = scene[k]
            renderer.render(R[k], t[k], draws=draws, distractors=distractors)
    return begin, time.perf_counter() - started, time.process_time() - cpu, time.time()


def _scenes(spec, renderer, jobs, poses) -> list:
    """Per job, per frame: (draws, distractors) as the whole path renders that frame
    (FrameMaker.scene), so the bare loop draws the same scenes; (None, ()) for a spec
    without [randomize] and [distractors]."""
    maker = FrameMaker(spec, renderer)
    return [[(draws, placement.distractors if placement else ())
             for draws, placement in (maker.scene(load_instance(spec, int(inst)), int(inst), int(pidx), R[k], t[k])
                                      for k, (inst, pidx) in enumerate(zip(job.instances, job.path_indices)))]
            for job, (R, t) in zip(jobs, poses)]


def bench_pyrender(base, cls: str, frames: int, sizes, workers_list, rounds: int) -> None:
    gl = make_renderer(base.replace(render=replace(base.render, renderer="pyrender")), "pyrender").gl_renderer()
    print(f"class {cls}, pyrender on GL_RENDERER {gl!r}, {os.cpu_count()} CPUs; {frames} frames per worker, best of "
          f"{rounds} interleaved runs; fps over all workers; whole, warm: from the first frame done (no worker "
          "start-up); whole / bare: of the best runs, and the median of each round's; split: ms per frame busy in "
          "each stage of the whole path (they overlap; summed over workers and threads; readback includes the wait "
          "for the drawing); CPU: ms of CPU per frame, all threads and worker processes (start-up included); "
          "render processes: the whole path's (on GPUs at most $SPM_CONTEXTS_PER_GPU, default 4, a GPU; the bare "
          "loop always runs one per worker); load: 1-minute load average as the row ended")
    print("| size | workers | render processes | bare fps | whole fps | whole fps, warm | whole / bare | "
          "whole / bare, median | bare CPU | whole CPU | " + " | ".join(STAGES) + " | load |")
    print("|---|---|---|---|---|---|---|---|---|---|" + "---|" * len(STAGES) + "---|")
    for size in sizes:
        spec = base.replace(image=type(base.image)(width=size, height=size, fov=base.image.fov),
                            render=replace(base.render, renderer="pyrender"))
        for workers in workers_list:
            n = frames * workers
            r = bench(spec, n, workers, rounds)
            split = " | ".join(f"{1e3 * r['split'].get(k, 0.0) / n:.3f}" for k in STAGES)
            print(f"| {size}x{size} | {workers} | {r['processes']} | {n / r['bare']:.0f} | {n / r['whole']:.0f} | "
                  f"{n / r['warm']:.0f} | "
                  f"{r['whole'] / r['bare']:.3f} | {r['paired']:.3f} | {1e3 * r['bare_cpu'] / n:.2f} | "
                  f"{1e3 * r['whole_cpu'] / n:.2f} | {split} | {os.getloadavg()[0]:.2f} |", flush=True)


def _blender_spec(spec, engine: str):
    """``spec`` rendered by Blender with ``engine``; Cycles keeps the spec's own settings
    (the shipped specs: 16 samples, 128x128)."""
    blender = replace(spec.render.blender, engine=engine)
    return spec.replace(render=replace(spec.render, renderer="blender", blender=blender))


def bench_blender(specs, engine: str, per_class: int, rounds: int = 2) -> dict:
    """Blender seconds per frame over ``per_class`` frames of each spec (the frames
    ``--limit`` picks, every instance):

    * bare: move the camera + ``bpy.ops.render.render()``, nothing else (no file);
    * ours: ``Renderer.render`` (the same, plus the multi-layer EXR written and read
      back and the arrays made), in this process;
    * whole: ``render_dataset`` (worker processes: bpy import, scene and mesh building,
      compositing, shard writing, manifest) with 1 and 2 workers.

    bare and ours are timed on the same frames, interleaved ``rounds`` times (the
    best of each counts), so load from other users of the machine hits both alike.
    """
    import bpy
    import mathutils

    from spm_data.core.poses import cv_to_gl_camera_to_world
    from spm_data.render.blender_scene import captured_output

    specs = [_blender_spec(spec, engine) for spec in specs]
    totals = {"bare": 0.0, "bare_border": 0.0, "ours": 0.0}
    frames = 0
    progress = stage(f"render_throughput: Blender {engine}, bare and ours, {per_class} frames of each of "
                     f"{len(specs)} specs", len(specs), "spec")
    for spec in specs:
        jobs = plan_shards(spec, "unused", limit=per_class)
        path = camera_path(spec.camera, spec.seed)
        renderer = make_renderer(spec, "blender")
        # Cycles renders only a border around the object (BlenderRenderer._set_border): bare is
        # timed both on full frames and with the same border.
        border = engine == "cycles" and hasattr(renderer, "_set_border")
        for job in jobs:
            R, t = path.poses(job.path_indices)
            for inst in sorted({int(i) for i in job.instances}):
                ks = [k for k, i in enumerate(job.instances) if int(i) == inst]
                renderer.set_mesh(load_instance(spec, inst))
                renderer.render(R[ks[0]], t[ks[0]])  # warm-up: the scene is built on the first frame
                best = {"bare": float("inf"), "bare_border": float("inf"), "ours": float("inf")}
                for _ in range(rounds):
                    for kind in best:
                        if kind == "bare_border" and not border:
                            continue
                        bpy.context.scene.render.use_border = False  # bare: the full frame
                        started = time.perf_counter()
                        if kind == "ours":
                            for k in ks:
                                renderer.render(R[k], t[k])
                        else:
                            with captured_output(renderer._log):  # Blender's per-frame lines, as ours does
                                for k in ks:
                                    renderer._camera.matrix_world = mathutils.Matrix(
                                        cv_to_gl_camera_to_world(R[k], t[k]).tolist())
                                    if kind == "bare_border":
                                        renderer._set_border(R[k], t[k])
                                    bpy.ops.render.render()
                        best[kind] = min(best[kind], time.perf_counter() - started)
                for kind in best:
                    totals[kind] += best[kind] if best[kind] < float("inf") else 0.0
                frames += len(ks)
        renderer.close()
        progress(1)
    progress.close()
    result = {"frames": frames, **{kind: total / frames for kind, total in totals.items()},
              "full_frames": sum(job.frames for spec in specs for job in plan_shards(spec, "unused"))}
    for workers in (1, 2):
        with tempfile.TemporaryDirectory() as out, stage(f"render_throughput: Blender {engine}, whole path, "
                                                         f"{workers} workers", unit="frame") as progress:
            executor = LocalExecutor(workers=workers, retries=1, recycle_after=RECYCLE_AFTER)
            summary = render_dataset(specs, out, limit=per_class, executor=executor, progress=progress)
            assert summary.frames == frames and not summary.failed, summary.report()
            result[f"whole_{workers}"] = summary.seconds / frames
    return result


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=512, help="pyrender: frames per worker")
    parser.add_argument("--sizes", default="128,256", help="pyrender: image sides, comma-separated")
    parser.add_argument("--workers-list", default="1,2,4,8", help="pyrender: worker counts, comma-separated")
    parser.add_argument("--rounds", type=int, default=3, help="pyrender: interleaved runs (the best counts)")
    parser.add_argument("--class", dest="cls", default="cup")
    parser.add_argument("--no-blender", action="store_true", help="pyrender only")
    parser.add_argument("--no-pyrender", action="store_true", help="Blender only")
    parser.add_argument("--blender-frames", type=int, default=96, help="Blender: frames of each shipped spec")
    parser.add_argument("--engines", default="cycles,workbench", help="Blender engines, comma-separated")
    args = parser.parse_args()
    if not args.no_pyrender:
        bench_pyrender(load_spec(find_spec(args.cls)), args.cls, args.frames, [int(v) for v in args.sizes.split(",")],
                       [int(v) for v in args.workers_list.split(",")], args.rounds)
    if args.no_blender:
        return
    specs = [load_spec(p) for p in all_spec_paths()]
    print(f"\nBlender {_blender_version()}, {args.blender_frames} frames of each of the {len(specs)} shipped specs "
          "(their own settings: 128x128, Cycles 16 samples). s/frame: bare = camera move + "
          "bpy.ops.render.render() (no file); ours = Renderer.render (plus the multi-layer EXR written and "
          "read back), both in this process, best of 2 interleaved; whole = render_dataset with 1 and 2 worker "
          "processes (bpy import, scene building, shard writing included). 'full set' extrapolates the "
          "faster whole s/frame to every frame of the shipped specs: an extrapolation, not a measurement.")
    print("(bare, border: the bare loop with the same render border ours sets, Cycles only)")
    print("| engine | frames | bare s/frame | bare, border | ours s/frame | ours / bare | ours / bare, border | "
          "whole s/frame, 1 worker | whole s/frame, 2 workers | whole / bare | full set (frames) | "
          "full set, extrapolated |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for engine in args.engines.split(","):
        r = bench_blender(specs, engine, args.blender_frames)
        whole = min(r["whole_1"], r["whole_2"])
        label = "Cycles (spec settings)" if engine == "cycles" else "Workbench"
        bb = r["bare_border"]
        bare_border = f"{bb:.4f}" if bb else "-"
        ratio_border = f"{r['ours'] / bb:.3f}" if bb else "-"
        print(f"| {label} | {r['frames']} | {r['bare']:.4f} | {bare_border} | {r['ours']:.4f} | "
              f"{r['ours'] / r['bare']:.3f} | {ratio_border} | {r['whole_1']:.4f} | {r['whole_2']:.4f} | "
              f"{whole / r['bare']:.3f} | {r['full_frames']:,} | {whole * r['full_frames'] / 60:.1f} min |",
              flush=True)


def _blender_version() -> str:
    import bpy

    return bpy.app.version_string


if __name__ == "__main__":
    main()

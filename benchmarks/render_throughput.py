"""Render throughput: seconds per frame of a bare render loop and of the whole path, and their ratio.

pyrender (one process, best of 3 interleaved runs, per resolution): (1) a bare loop
of renderer.render over the frames, with the frames' own draws and distractors (made
before the loop) and (2) the whole `spm-data render` path for the same frames (path
generation, meshes, draws, distractors, compositing, HDF5 shard writing, manifest);
prints s/frame and fps for both, overhead = 1 - bare / whole and whole / bare.
Targets (issue 26): overhead <= 10% at 128x128 and <= 15% at 256x256.

Blender (--blender-frames of each shipped spec, at the spec's settings, Cycles and
Workbench): bare = camera move + bpy.ops.render.render() and nothing else (no file
written: Blender's own cost for the frame); ours = Renderer.render; whole =
render_dataset with 1 and 2 worker processes; and, for the full set of shipped
specs, an extrapolation (whole s/frame x frames), not a measurement.
Targets: Cycles ours / bare <= 1.05 and the full set <= 12 min; Workbench ours / bare <= 1.3.
Progress on stderr (a bar on a terminal, a line every $SPM_PROGRESS_EVERY s, default 10, elsewhere).
"""

import argparse
import sys
from dataclasses import replace
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from spm_data.commands.cli_support import stage  # noqa: E402
from spm_data.core.paths import camera_path  # noqa: E402
from spm_data.render import make_renderer  # noqa: E402
from spm_data.core.instances import load_instance  # noqa: E402
from spm_data.commands.render_frames import FrameMaker  # noqa: E402
from spm_data.commands.render_jobs import RECYCLE_AFTER, plan_shards, render_dataset  # noqa: E402
from spm_data.core.specs import all_spec_paths, find_spec, load_spec  # noqa: E402
from spm_data.jobs.executor import LocalExecutor  # noqa: E402


def bench(spec, frames: int, renderer_name: str, repeats: int = 3) -> tuple[float, float]:
    """Best-of-``repeats`` seconds for the bare loop and the whole path, interleaved
    so that load from other users of a shared machine hits both alike."""
    size = f"{spec.image.width}x{spec.image.height}"
    with stage(f"render_throughput: {renderer_name} {size}, bare loop and whole path, {frames} frames, "
               f"{repeats} rounds", 2 * frames * repeats, "frame") as progress:
        runs = [_bench_once(spec, frames, renderer_name, progress) for _ in range(repeats)]
    return min(r[0] for r in runs), min(r[1] for r in runs)


def _bench_once(spec, frames: int, renderer_name: str, progress=lambda n: None) -> tuple[float, float]:
    jobs = plan_shards(spec, "unused", limit=frames)
    path = camera_path(spec.camera, spec.seed)
    poses = [path.poses(job.path_indices) for job in jobs]  # outside the timed loop
    renderer = make_renderer(spec, renderer_name)
    # Warm up: GL context, shader compilation, mesh building (cached for both loops).
    for inst in sorted({int(i) for j in jobs for i in j.instances}):
        renderer.set_mesh(load_instance(spec, inst))
        renderer.render(poses[0][0][0], poses[0][1][0])
    scenes = _scenes(spec, renderer, jobs, poses)  # outside the timed loop
    started = time.perf_counter()
    for job, (R, t), scene in zip(jobs, poses, scenes):
        current = None
        for k, inst in enumerate(job.instances):
            if inst != current:
                renderer.set_mesh(load_instance(spec, int(inst)))
                current = inst
            draws, distractors = scene[k]
            renderer.render(R[k], t[k], draws=draws, distractors=distractors)
    bare = time.perf_counter() - started
    progress(frames)
    with tempfile.TemporaryDirectory() as out:
        started = time.perf_counter()
        summary = render_dataset([spec], out, limit=frames)
        whole = time.perf_counter() - started
    progress(frames)
    assert summary.frames == frames
    return bare, whole


def _scenes(spec, renderer, jobs, poses) -> list:
    """Per job, per frame: (draws, distractors) as the whole path renders that frame
    (FrameMaker.scene), so the bare loop draws the same scenes; (None, ()) for a spec
    without [randomize] and [distractors]."""
    maker = FrameMaker(spec, renderer)
    return [[(draws, placement.distractors if placement else ())
             for draws, placement in (maker.scene(load_instance(spec, int(inst)), int(inst), int(pidx), R[k], t[k])
                                      for k, (inst, pidx) in enumerate(zip(job.instances, job.path_indices)))]
            for job, (R, t) in zip(jobs, poses)]


def bench_pyrender(base, cls: str, frames: int) -> None:
    print(f"class {cls}, {frames} frames, 1 process, best of 3 interleaved runs; overhead = 1 - bare / whole "
          "(the share of the run outside renderer.render); whole / bare = the run's time over the bare loop's")
    print("| renderer | size | bare s/frame | whole s/frame | bare render fps | spm-data render fps | overhead | "
          "whole / bare |")
    print("|---|---|---|---|---|---|---|---|")
    for size in (128, 256):
        spec = base.replace(image=type(base.image)(width=size, height=size, fov=base.image.fov),
                            render=replace(base.render, renderer="pyrender"))
        bare, whole = bench(spec, frames, "pyrender")
        print(f"| pyrender | {size}x{size} | {bare / frames:.5f} | {whole / frames:.5f} | {frames / bare:.0f} | "
              f"{frames / whole:.0f} | {100 * (1 - bare / whole):.1f}% | {whole / bare:.3f} |", flush=True)


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
    parser.add_argument("--frames", type=int, default=512)
    parser.add_argument("--class", dest="cls", default="cup")
    parser.add_argument("--no-blender", action="store_true", help="pyrender only")
    parser.add_argument("--no-pyrender", action="store_true", help="Blender only")
    parser.add_argument("--blender-frames", type=int, default=96, help="Blender: frames of each shipped spec")
    parser.add_argument("--engines", default="cycles,workbench", help="Blender engines, comma-separated")
    args = parser.parse_args()
    if not args.no_pyrender:
        bench_pyrender(load_spec(find_spec(args.cls)), args.cls, args.frames)
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

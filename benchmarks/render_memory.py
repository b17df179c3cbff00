"""Worker memory while rendering large images, and while planning a huge camera grid.

Each measurement runs in a fresh Python process, which reports its own peak
resident memory (VmHWM, /proc/self/status) and wall time:

* render: one class (the procedural cup, one instance, pyrender, black
  background) of FRAMES frames into one shard of FRAMES frames
  (``frames_per_shard = FRAMES``), at each image size; once as `spm-data render`
  writes it (streamed, render_jobs.block_frames frames at a time) and once with
  the whole shard buffered in memory (what the renderer did before streaming:
  every frame of the shard in RAM before writing, simulated by making the block
  the whole shard).
* plan: ``plan_shards(limit=4)`` on a spec with 0.01-degree azimuth and
  elevation steps (216 million views x 4 instances), and, for reference, a
  process that only imports spm_data.pipelines.render_jobs.

    python benchmarks/render_memory.py [--sizes 1024 2048 4096] [--frames 16] [--no-buffered]

A line on stderr as each measurement starts, and every $SPM_PROGRESS_EVERY s (default 10) while
it runs off a terminal (a bar on one).
"""

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

SPEC = """class = "cup"
seed = 1
[mesh]
instances = {instances}
[camera]
azimuth = [0, {az_stop}, {az_step}]
elevation = [0, {el_stop}, {el_step}]
distances = [0.6]
[image]
width = {size}
height = {size}
[render]
renderer = "pyrender"
frames_per_shard = {per}
"""


def peak_mb() -> float:
    from blender_memory import memory_mb  # this folder is on sys.path when run as a script

    return memory_mb()[1]


def child(mode: str, size: int, frames: int) -> dict:
    """Runs in the measured process; returns what it measured."""
    from spm_data.pipelines import render_jobs
    from spm_data.pipelines.render_jobs import load_run_specs, plan_shards, render_dataset

    started = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        specs = Path(tmp) / "specs"
        specs.mkdir()
        if mode == "import":
            return {"peak_mb": peak_mb(), "seconds": time.perf_counter() - started}
        if mode == "plan":
            (specs / "cup.toml").write_text(SPEC.format(az_stop=359.99, az_step=0.01, el_stop=60, el_step=0.01,
                                                        size=128, per=256, instances=4))
            import tracemalloc

            tracemalloc.start()
            spec = load_run_specs(["cup"], specs_dir=specs)[0]
            jobs = plan_shards(spec, Path(tmp) / "out", limit=4)
            traced = tracemalloc.get_traced_memory()[1] / 2**20
            assert sum(j.frames for j in jobs) == 4
            return {"peak_mb": peak_mb(), "seconds": time.perf_counter() - started, "traced_mb": traced}
        (specs / "cup.toml").write_text(SPEC.format(az_stop=5 * (frames - 1), az_step=5, el_stop=30, el_step=30,
                                                    size=size, per=frames, instances=1))
        spec = load_run_specs(["cup"], specs_dir=specs)[0]
        if mode == "buffered":
            render_jobs.BLOCK_BYTES = 1 << 62  # the whole shard in one block: the old behaviour
        block = min(frames, render_jobs.block_frames(size, size))
        summary = render_dataset([spec], Path(tmp) / "out", limit=frames)
        assert summary.frames == frames and not summary.failed, summary.report()
        return {"peak_mb": peak_mb(), "seconds": time.perf_counter() - started, "block": block}


def measure(mode: str, size: int = 0, frames: int = 0) -> dict:
    from spm_data.jobs.progress import stage

    env = {**os.environ, "PYOPENGL_PLATFORM": os.environ.get("PYOPENGL_PLATFORM", "egl")}
    what = f"{mode}, {frames} frames of {size}x{size}" if size else mode
    with stage(f"render_memory: {what}, in a child process"):
        out = subprocess.run([sys.executable, __file__, "--child", mode, str(size), str(frames)],
                             capture_output=True, text=True, env=env, cwd=ROOT)
    if out.returncode != 0:
        return {"error": (out.stderr.strip().splitlines() or ["exit status %d" % out.returncode])[-1]}
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[1024, 2048, 4096])
    parser.add_argument("--frames", type=int, default=16)
    parser.add_argument("--no-buffered", action="store_true", help="skip the whole-shard-in-memory runs")
    parser.add_argument("--child", nargs=3, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        print(json.dumps(child(args.child[0], int(args.child[1]), int(args.child[2]))))
        return

    def cell(r: dict, digits: int = 1) -> str:
        return r["error"] if "error" in r else f"{r['peak_mb']:,.0f} MB | {r['seconds']:.{digits}f} s"

    print(f"Peak RSS of one process rendering {args.frames} frames into one shard of {args.frames} "
          f"(pyrender, cup, black background)\n")
    print("| image | frames per block | streamed: peak RSS | time | whole shard buffered: peak RSS | time |")
    print("|---|---|---|---|---|---|")
    for size in args.sizes:
        streamed = measure("streamed", size, args.frames)
        buffered = {"error": "skipped | -"} if args.no_buffered else measure("buffered", size, args.frames)
        print(f"| {size}x{size} | {streamed.get('block', '-')} | {cell(streamed)} | {cell(buffered)} |", flush=True)
    imports, plan = measure("import"), measure("plan")
    print("\n| process | peak RSS | time |\n|---|---|---|")
    print(f"| imports only (spm_data.pipelines.render_jobs) | {cell(imports, 3)} |")
    print(f"| load the spec + plan --limit 4, 0.01-degree grid (4 x 216,036,000 frames) | {cell(plan, 3)} |")
    if "traced_mb" in plan:
        print(f"\nPython allocations while loading and planning (tracemalloc peak): {plan['traced_mb']:.2f} MB")


if __name__ == "__main__":
    main()

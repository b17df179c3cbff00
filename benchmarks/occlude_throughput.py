"""`spm-data occlude` throughput on 128x128 shards (target: 2,000 frames/s in one process,
checksums included, and faster with --workers 2 than with one), and what verifying the
inputs costs of it.

Renders a 1,024-frame cup set with pyrender once (or reads ``--in DIR``, e.g. one
kept with ``--keep DIR``), then times, best of 3 each: (1) placing the rectangles alone
(occlude_mask + apply_occlusion, in memory); (2) verifying every input (its SHA-256,
attributes and layout, as occlude does before writing); (3) the whole command (verify,
read, occlude, write shards, manifest) in this process, with its CPU time; (4) the same
with ``--workers 2``. Before each timed step this process forgets what it verified, so
every input is hashed again, as in a fresh ``spm-data occlude``. Prints frames per
second, the verification's share of the one-process command and the load average.

    python benchmarks/occlude_throughput.py [--in DIR | --keep DIR]

Progress on stderr (a bar on a terminal, a line every $SPM_PROGRESS_EVERY s, default 10, elsewhere).
"""

import argparse
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))


def main(frames: int = 1024) -> None:
    # Imports here, not at the top: a spawned worker imports this script again (as
    # __mp_main__), and the renderer's imports (trimesh, scipy) would cost each worker ~1 s.
    import numpy as np

    from spm_data.jobs.progress import stage
    from spm_data.pipelines.occlude_jobs import occlude_dataset
    from spm_data.core.occlusion import apply_occlusion, occlude_mask
    from spm_data.io.shards import forget_checks, list_shards, read_shard, verify_shard
    from spm_data.jobs.executor import LocalExecutor

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--in", dest="source", type=Path, help="occlude this folder instead of a fresh render")
    parser.add_argument("--keep", type=Path, help="render into this folder (kept) instead of a temporary one")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        source = args.source or args.keep or tmp / "in"
        if args.source is None:
            from spm_data.pipelines.render_jobs import load_run_specs, render_dataset

            with stage(f"occlude_throughput: rendering {frames} frames", unit="frame") as progress:
                render_dataset(load_run_specs(["cup"], renderer="pyrender"), source, limit=frames, progress=progress)
        data = [read_shard(p, ["rgb", "mask"]) for p in list_shards(source)]
        frames = sum(len(d["mask"]) for d in data)
        rng = np.random.default_rng(0)
        best = {"place": [], "verify": [], "one": [], "cpu": [], "two": []}
        for attempt in range(3):
            print(f"occlude_throughput: pass {attempt + 1} of 3: verify, place, occlude with 1 and 2 workers",
                  file=sys.stderr, flush=True)
            forget_checks()
            started = time.perf_counter()
            for p in list_shards(source):  # what occlude checks before writing anything
                verify_shard(p)
            best["verify"].append(time.perf_counter() - started)
            started = time.perf_counter()
            for d in data:
                for rgb, mask in zip(d["rgb"], d["mask"]):
                    occ = occlude_mask(mask, rng.uniform(0, 0.6), rng)
                    apply_occlusion(rgb, mask, occ.rects)
            best["place"].append(time.perf_counter() - started)
            forget_checks()
            started, cpu = time.perf_counter(), time.process_time()
            with stage(f"occlude_throughput: occlude, one process (pass {attempt + 1})", unit="frame") as progress:
                summary = occlude_dataset(source, tmp / f"out{attempt}", low=0.0, high=0.6, progress=progress)
            best["one"].append(time.perf_counter() - started)
            best["cpu"].append(time.process_time() - cpu)
            assert summary.frames == frames
            forget_checks()
            started = time.perf_counter()
            with stage(f"occlude_throughput: occlude, 2 workers (pass {attempt + 1})", unit="frame") as progress:
                occlude_dataset(source, tmp / f"out-2w{attempt}", low=0.0, high=0.6, executor=LocalExecutor(workers=2),
                                progress=progress)
            best["two"].append(time.perf_counter() - started)
            assert sorted(os.listdir(tmp / f"out-2w{attempt}")) == sorted(os.listdir(tmp / f"out{attempt}"))
            shutil.rmtree(tmp / f"out-2w{attempt}")
        fps = {k: frames / min(v) for k, v in best.items()}
        print(f"{frames} frames of 128x128, best of 3; load average {', '.join(f'{x:.1f}' for x in os.getloadavg())} "
              f"on {os.cpu_count()} cores")
        print(f"| step | frames/s |\n|---|---|\n| place rectangles (in memory, one core) | {fps['place']:.0f} |\n"
              f"| verify every input (SHA-256, attributes, layout; part of the command below) | {fps['verify']:.0f} |\n"
              f"| spm-data occlude (verify, read, occlude, write, manifest), one process | {fps['one']:.0f} |\n"
              f"| the same per CPU-second (all its threads) | {fps['cpu']:.0f} |\n"
              f"| spm-data occlude --workers 2 | {fps['two']:.0f} |")
        print(f"verification: {min(best['verify']) / min(best['one']):.0%} of the one-process command; "
              f"--workers 2 / one process: {min(best['one']) / min(best['two']):.2f}x")
        print(f"unreachable frames in the last run: {sum(r['unreachable'] for r in summary.results.values())}")


if __name__ == "__main__":
    main()

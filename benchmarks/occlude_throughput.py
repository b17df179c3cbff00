"""`spm-data occlude` throughput on 128x128 shards, one process (target: 2,000 frames/s),
and what verifying the inputs' checksums costs of it.

Renders a 1,024-frame cup set with pyrender once (or reads ``--in DIR``, e.g. one
kept with ``--keep DIR``), then times (1) placing the rectangles alone
(occlude_mask + apply_occlusion, in memory) and (2) the whole command (read,
occlude, write shards, manifest), with one process and with ``--workers 2``, best
of 3 each. Prints frames per second.

    python benchmarks/occlude_throughput.py [--in DIR | --keep DIR]
"""

import argparse
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from spm_data.commands.occlude_jobs import occlude_dataset  # noqa: E402
from spm_data.core.occlusion import apply_occlusion, occlude_mask  # noqa: E402
from spm_data.commands.render_jobs import load_run_specs, render_dataset  # noqa: E402
from spm_data.io.shards import list_shards, read_shard, verify_shard  # noqa: E402
from spm_data.jobs.executor import LocalExecutor  # noqa: E402


def main(frames: int = 1024) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--in", dest="source", type=Path, help="occlude this folder instead of a fresh render")
    parser.add_argument("--keep", type=Path, help="render into this folder (kept) instead of a temporary one")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        source = args.source or args.keep or tmp / "in"
        if args.source is None:
            render_dataset(load_run_specs(["cup"], renderer="pyrender"), source, limit=frames)
        data = [read_shard(p, ["rgb", "mask"]) for p in list_shards(source)]
        frames = sum(len(d["mask"]) for d in data)
        rng = np.random.default_rng(0)
        best_mem = best_cmd = best_verify = best_two = float("inf")
        for attempt in range(3):
            started = time.perf_counter()
            for p in list_shards(source):  # what occlude checks before writing anything
                verify_shard(p)
            best_verify = min(best_verify, time.perf_counter() - started)
            started = time.perf_counter()
            for d in data:
                for rgb, mask in zip(d["rgb"], d["mask"]):
                    occ = occlude_mask(mask, rng.uniform(0, 0.6), rng)
                    apply_occlusion(rgb, mask, occ.rects)
            best_mem = min(best_mem, time.perf_counter() - started)
            started = time.perf_counter()
            summary = occlude_dataset(source, tmp / f"out{attempt}", low=0.0, high=0.6)
            best_cmd = min(best_cmd, time.perf_counter() - started)
            assert summary.frames == frames
            started = time.perf_counter()
            occlude_dataset(source, tmp / f"out-2w{attempt}", low=0.0, high=0.6, executor=LocalExecutor(workers=2))
            best_two = min(best_two, time.perf_counter() - started)
            shutil.rmtree(tmp / f"out-2w{attempt}")
        print(f"{frames} frames of 128x128, best of 3")
        print(f"| step | frames/s |\n|---|---|\n| place rectangles (in memory, one core) | {frames / best_mem:.0f} |\n"
              f"| verify every input chunk's checksum (part of the command below) | {frames / best_verify:.0f} |\n"
              f"| spm-data occlude (verify, read, occlude, write, manifest), one process | {frames / best_cmd:.0f} |\n"
              f"| spm-data occlude --workers 2 | {frames / best_two:.0f} |")
        print(f"unreachable frames in the last run: {sum(r['unreachable'] for r in summary.results.values())}")


if __name__ == "__main__":
    main()

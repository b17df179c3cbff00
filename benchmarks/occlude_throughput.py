"""`spm-data occlude` throughput on 128x128 shards, one process (target: 2,000 frames/s),
and what verifying the inputs' checksums costs of it.

Renders a 1,024-frame cup set with pyrender once, then times (1) placing the
rectangles alone (occlude_mask + apply_occlusion, in memory) and (2) the whole
command (read, occlude, write shards, manifest). Prints frames per second.
"""

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
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        render_dataset(load_run_specs(["cup"], renderer="pyrender"), tmp / "in", limit=frames)
        data = [read_shard(p, ["rgb", "mask"]) for p in list_shards(tmp / "in")]
        rng = np.random.default_rng(0)
        best_mem = best_cmd = best_verify = float("inf")
        for attempt in range(3):
            started = time.perf_counter()
            for p in list_shards(tmp / "in"):  # what occlude checks before writing anything
                verify_shard(p)
            best_verify = min(best_verify, time.perf_counter() - started)
            started = time.perf_counter()
            for d in data:
                for rgb, mask in zip(d["rgb"], d["mask"]):
                    occ = occlude_mask(mask, rng.uniform(0, 0.6), rng)
                    apply_occlusion(rgb, mask, occ.rects)
            best_mem = min(best_mem, time.perf_counter() - started)
            started = time.perf_counter()
            summary = occlude_dataset(tmp / "in", tmp / f"out{attempt}", low=0.0, high=0.6)
            best_cmd = min(best_cmd, time.perf_counter() - started)
            assert summary.frames == frames
        started = time.perf_counter()
        occlude_dataset(tmp / "in", tmp / "out-2w", low=0.0, high=0.6, executor=LocalExecutor(workers=2))
        two = time.perf_counter() - started
        print(f"{frames} frames of 128x128, best of 3 (2 workers: one run)")
        print(f"| step | frames/s |\n|---|---|\n| place rectangles (in memory, one core) | {frames / best_mem:.0f} |\n"
              f"| verify every input chunk's checksum (part of the command below) | {frames / best_verify:.0f} |\n"
              f"| spm-data occlude (verify, read, occlude, write, manifest), one process | {frames / best_cmd:.0f} |\n"
              f"| spm-data occlude --workers 2 | {frames / two:.0f} |")
        print(f"unreachable frames in the last run: {sum(r['unreachable'] for r in summary.results.values())}")


if __name__ == "__main__":
    main()

"""What checking every byte of a shard on open costs (issue 22; docs/reliability.md).

Renders a 1,024-frame cup set at 128x128 with pyrender once, then reads every frame
(rgb, depth, mask and the labels) three ways, each with and without the whole-file
SHA-256 check (seal.py; "without" skips only that check, the Fletcher-32 and CRC-32
checks stay): ``read_shard`` of whole shards, ``ShardDataset`` a frame at a time, and
the hash alone. Each pass starts with nothing verified (seal.forget). Best of 3.

    python benchmarks/verify_cost.py [--frames 1024]

Progress on stderr (a bar on a terminal, a line every $SPM_PROGRESS_EVERY s, default 10, elsewhere).
"""

import argparse
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from spm_data.jobs.progress import stage  # noqa: E402
from spm_data.pipelines.render_jobs import load_run_specs, render_dataset  # noqa: E402
from spm_data.io.loaders import ShardDataset  # noqa: E402
from spm_data.io.shards import list_shards, read_shard, reader, seal  # noqa: E402

FIELDS = ["rgb", "depth", "mask", "pose", "K", "class_name"]


def best(call, what: str, repeat=3) -> float:
    times = []
    with stage(f"verify_cost: {what}, best of {repeat}", repeat, "pass") as progress:
        for _ in range(repeat):
            seal.forget()
            started = time.perf_counter()
            call()
            times.append(time.perf_counter() - started)
            progress(1)
    return min(times)


def header_only(path) -> str:
    """The digest the header names, nothing hashed (the check skipped)."""
    with open(path, "rb") as fh:
        return seal.stored_digest(fh.read(seal.USERBLOCK))


def main(frames: int) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) / "in"
        with stage(f"verify_cost: rendering {frames} frames", unit="frame") as progress:
            render_dataset(load_run_specs(["cup"], renderer="pyrender"), folder, limit=frames, progress=progress)
        shards = list_shards(folder)
        size = sum(p.stat().st_size for p in shards)

        def whole():
            for p in shards:
                read_shard(p, FIELDS)

        def one_at_a_time():
            ds = ShardDataset(folder, fields=FIELDS)
            for i in range(len(ds)):
                ds[i]
            ds.close()

        def hash_only():
            for p in shards:
                seal.verified_digest(p)

        checked = {"read_shard": best(whole, "read_shard, checked"),
                   "ShardDataset": best(one_at_a_time, "ShardDataset, checked"), "hash": best(hash_only, "SHA-256")}
        real = reader.verified_digest
        reader.verified_digest = header_only
        try:
            unchecked = {"read_shard": best(whole, "read_shard, unchecked"),
                         "ShardDataset": best(one_at_a_time, "ShardDataset, unchecked")}
        finally:
            reader.verified_digest = real
    print(f"{frames} frames of 128x128 in {len(shards)} shards, {size / 1e6:.1f} MB; best of 3")
    print("| read | frames/s with the check | without | cost |\n|---|---|---|---|")
    for name in unchecked:
        w, wo = frames / checked[name], frames / unchecked[name]
        print(f"| {name} | {w:,.0f} | {wo:,.0f} | {100 * (checked[name] / unchecked[name] - 1):.0f}% |")
    print(f"| SHA-256 of every byte alone | {frames / checked['hash']:,.0f} ({size / 1e6 / checked['hash']:,.0f} MB/s) "
          f"| | |")


if __name__ == "__main__":
    parser = argparse.ArgumentParser()
    parser.add_argument("--frames", type=int, default=1024)
    main(parser.parse_args().frames)

"""Flip one bit of every metadata byte of a small shard and read it back (issue 22).

A 4-frame shard of 8x10 pixels with every field; each byte outside the chunks' stored
data is flipped in turn (bit = position mod 8) and the shard read whole with
``read_shard``. Counts: refused (a ShardError naming the shard, by its kind), silent
wrong reads (values differ, no error), reads equal to the original, and tracebacks
(any other exception). ``--stride N`` scans every Nth byte. tests/system/test_flip_scan.py
is the quick version run by the test suite.

    python benchmarks/flip_scan.py [--stride 1]

Progress on stderr (a bar on a terminal, a line every $SPM_PROGRESS_EVERY s, default 10, elsewhere).
"""

import argparse
import collections
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from spm_data.jobs.progress import tracked  # noqa: E402
from spm_data.errors import ShardError  # noqa: E402
from spm_data.io.shards import read_shard, write_shard  # noqa: E402
from tests.helpers import make_arrays, payload_positions  # noqa: E402


def same(a: dict, b: dict) -> bool:
    return a.keys() == b.keys() and all(np.array_equal(a[k], b[k]) for k in a)


def main(stride: int) -> None:
    tmp = Path(tempfile.mkdtemp())
    clean = write_shard(tmp / "s.h5", make_arrays(n=4, h=8, w=10), {"renderer": "x", "seed": 0, "spec": "class"})
    truth, data = read_shard(clean), clean.read_bytes()
    inside = payload_positions(clean)
    metadata = [p for p in range(len(data)) if p not in inside][::stride]
    counts = collections.Counter()
    path = tmp / "flipped.h5"
    started = time.perf_counter()
    for p in tracked(metadata, "flip_scan: flipping metadata bytes", "flip"):
        flipped = bytearray(data)
        flipped[p] ^= 1 << (p % 8)
        path.write_bytes(bytes(flipped))
        try:
            got = read_shard(path)
        except ShardError as exc:
            message = str(exc)
            assert message.startswith(f"{path}: "), message
            kind = ("field or attribute named" if "fails its" in message or "missing" in message else
                    "not a readable HDF5 shard" if "not a readable HDF5" in message else
                    "header damaged" if "header" in message else
                    "bytes differ from the SHA-256" if "SHA-256" in message else message[len(str(path)) + 2:][:60])
            counts["refused: " + kind] += 1
        except Exception as exc:  # noqa: BLE001 - what the scan looks for
            counts[f"traceback: {type(exc).__name__}"] += 1
        else:
            counts["read, equal to the original" if same(got, truth) else "SILENT WRONG READ"] += 1
    seconds = time.perf_counter() - started
    print(f"shard {len(data):,} bytes, {len(data) - len(inside):,} metadata bytes, {len(metadata):,} flipped "
          f"(stride {stride}) in {seconds:.0f} s")
    for kind, n in counts.most_common():
        print(f"{n:>7,}  {kind}")
    print(f"silent wrong reads: {counts['SILENT WRONG READ']}, "
          f"tracebacks: {sum(n for k, n in counts.items() if k.startswith('traceback'))}")


if __name__ == "__main__":
    parser = argparse.ArgumentParser()
    parser.add_argument("--stride", type=int, default=1)
    main(parser.parse_args().stride)

"""Every byte of one feature memo entry and one `.spm-features` cache file flipped, every
truncation, and 50 memo entries rotated (issue 35): nothing damaged is ever served.

The memo entry and the cache file are made from real renders (one 128-pixel cup shard of 48
views, pyrender; N3M's SIFT memo and the shard's SPM feature cache). Each flip (bit = position
mod 8) and each cut is read back through the readers every run uses (``load_entry`` with the
entry's key, ``read_cache`` with the shard's SHA-256 and configuration). Counts: refused (the
reader says "not usable": recomputed by the caller), equal (a byte the format ignores: the
same arrays come back), silent wrong reads (different arrays, no refusal) and tracebacks
(any exception escaping the reader). Then 50 memo entries are renamed in a ring and read
for their own images.

    python benchmarks/cache_scan.py [--stride 1] [--out DIR]    # --stride 1: 1.5 M reads, about an hour
"""

from __future__ import annotations

import argparse
import collections
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from spm_data.pipelines.render_jobs import load_run_specs, render_dataset  # noqa: E402
from spm_data.io.shards import list_shards, shard_digest  # noqa: E402
from spm_model.base import feature_memo  # noqa: E402
from spm_model.bench import feature_cache  # noqa: E402
from spm_model.spm.features import FeatureConfig  # noqa: E402
from tests.helpers import write_pyrender_128_spec  # noqa: E402


def same(a, b) -> bool:
    if isinstance(a, dict):
        return a.keys() == b.keys() and all(np.array_equal(a[k], b[k]) for k in a)
    return len(a) == len(b) and all(np.array_equal(x, y) for x, y in zip(a, b))


def scan(path: Path, read, truth, stride: int, label: str) -> collections.Counter:
    """Flip every ``stride``-th byte of ``path`` and cut it at every ``stride``-th length, reading
    each with ``read()``; the file is put back after."""
    good = path.read_bytes()
    counts = collections.Counter()
    started, last = time.monotonic(), time.monotonic()
    positions = range(0, len(good), stride)
    for n, (kind, i) in enumerate([("flip", i) for i in positions] + [("cut", i) for i in positions]):
        if kind == "flip":
            bad = bytearray(good)
            bad[i] ^= 1 << (i % 8)
            path.write_bytes(bytes(bad))
        else:
            path.write_bytes(good[:i])
        try:
            got = read()
        except Exception as exc:  # noqa: BLE001 - counting what escapes the reader is the point
            counts[f"{kind}: traceback {type(exc).__name__}"] += 1
            continue
        counts[f"{kind}: " + ("refused" if got is None else "equal" if same(got, truth) else "SILENT WRONG")] += 1
        if time.monotonic() - last > 10:
            last = time.monotonic()
            done = n + 1
            left = (2 * len(positions) - done) * (last - started) / done
            print(f"  {label}: {done:,}/{2 * len(positions):,} reads, {left:.0f} s left", flush=True)
    path.write_bytes(good)
    return counts


def main(stride: int, out: Path) -> None:
    out.mkdir(parents=True, exist_ok=True)
    specs = out / "specs"
    specs.mkdir(exist_ok=True)
    write_pyrender_128_spec(specs, "cup", seed=1, az_stop=115, el=20, per_shard=48)
    render_dataset(load_run_specs(all_classes=True, specs_dir=specs), out / "shards")
    shard = list_shards(out / "shards")[0]
    config = FeatureConfig(ellipse="direct")
    feature_cache.load_features(out / "shards", config)
    cache = feature_cache.cache_path(shard, config)
    digest = shard_digest(shard)
    feature_cache._warned[0] = True   # the warning is tested elsewhere; here only what comes back counts
    truth = feature_cache.read_cache(cache, digest, config)
    print(f"feature cache {cache.name}: {cache.stat().st_size:,} bytes")
    counts = scan(cache, lambda: feature_cache.read_cache(cache, digest, config), truth, stride, "cache file")
    print("  " + ", ".join(f"{k} {v:,}" for k, v in sorted(counts.items())))

    memo = out / "memo"
    feature_memo.use_folder(memo)
    rng = np.random.default_rng(0)
    images = [rng.integers(0, 255, (16, 16, 3), dtype=np.uint8) for _ in range(50)]
    for img in images:
        feature_memo.memoized(("scan", 1), (img,), lambda img=img: (img.sum(axis=2).astype(np.float64),
                                                                   np.flatnonzero(img[..., 0].ravel() > 128)))
    entries = sorted(memo.glob("*/*.feat"))
    entry, key = entries[0], bytes.fromhex(entries[0].stem)
    truth = feature_memo.load_entry(entry, key)
    print(f"memo entry {entry.name}: {entry.stat().st_size:,} bytes")
    counts = scan(entry, lambda: feature_memo.load_entry(entry, key), truth, 1, "memo entry")   # every byte: small
    print("  " + ", ".join(f"{k} {v:,}" for k, v in sorted(counts.items())))
    data = [p.read_bytes() for p in entries]
    for p, d in zip(entries, data[1:] + data[:1]):
        p.write_bytes(d)
    served = sum(feature_memo.load_entry(p, bytes.fromhex(p.stem)) is not None for p in entries)
    print(f"memo entries rotated in a ring: {len(entries)}, served for the wrong image: {served}")


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--stride", type=int, default=1,
                        help="scan every Nth byte and length of the cache file (the memo entry: every one)")
    parser.add_argument("--out", default=None, help="working folder (default: a new temporary one)")
    args = parser.parse_args()
    main(args.stride, Path(args.out) if args.out else Path(tempfile.mkdtemp()))

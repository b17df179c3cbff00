"""What ShardDataset's verification costs a training loop on a large folder (issue 36 item 7).

Makes a 20,000-frame folder of 128x128 shards (256 frames each, written with
``write_shard``: a shaded disc with per-pixel noise, so the shards compress about as
textured renders do), or
takes ``--folder``, then reads every frame (rgb, depth, mask, pose, K, class_name)
twice, one frame at a time in order, two ways (taking turns pass by pass):

* ``ShardDataset`` (verified: every byte of a shard against the SHA-256 in its header on
  its first read in the process, before any of its frames is returned, its attributes'
  CRC-32, and HDF5's Fletcher-32 on every chunk read; frame counts from the manifest);
* plain h5py (the baseline: no SHA-256, no attribute check; each shard opened once
  and its datasets kept, ``ds[j]``, strings through ``asstr()``).

Each way starts with nothing verified in this process (``forget_checks``, as a fresh
training run starts); the files are in the page cache for both (just written or read).
Printed: the time to the first item (construction and ``[0]``), items/s of the first
and of the second full pass (wall clock, and per CPU-second of this process, which the
load of a shared machine moves less), and verified / unverified.

    python benchmarks/shard_dataset.py [--folder DIR] [--frames 20000] [--size 128] [--repeat 1]

Progress on stderr (a bar on a terminal, a line every $SPM_PROGRESS_EVERY s, default 10, elsewhere).
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from spm_data.jobs.progress import stage  # noqa: E402
from spm_data.io.folders import open_folder  # noqa: E402
from spm_data.io.loaders import ShardDataset  # noqa: E402
from spm_data.io.shards import FIELDS as SCHEMA, forget_checks, read_manifest, write_manifest, write_shard  # noqa: E402

FIELDS = ("rgb", "depth", "mask", "pose", "K", "class_name")
PER_SHARD = 256


def frames_arrays(n: int, size: int, seed: int) -> dict:
    """Every schema field for ``n`` frames: a shaded disc on a ramp background (rgb, depth,
    mask), varying frame to frame as a turntable render does, with per-pixel noise (sensor
    grain, texture, depth jitter) so the images compress about as a textured render does;
    labels random."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:size, 0:size].astype(np.float32) / size
    arrays = {}
    cx, cy = 0.5 + 0.1 * rng.standard_normal((2, n, 1, 1)).astype(np.float32)
    r = 0.25 + 0.05 * np.abs(rng.standard_normal((n, 1, 1))).astype(np.float32)
    d2 = ((xx - cx) ** 2 + (yy - cy) ** 2) / r ** 2
    inside = d2 < 1
    shade = np.clip(1 - d2, 0, 1)
    colour = rng.integers(60, 230, (n, 1, 1, 3))
    grain = rng.integers(-6, 7, (n, size, size, 3), dtype=np.int16)
    rgb = np.where(inside[..., None], shade[..., None] * colour, 30 + 20 * yy[..., None]) + grain
    arrays["rgb"] = np.clip(rgb, 0, 255).astype(np.uint8)
    jitter = rng.standard_normal((n, size, size), dtype=np.float32) * 1e-3
    arrays["depth"] = np.where(inside, 0.6 - 0.1 * np.sqrt(shade) + jitter, 0).astype(np.float32)
    arrays["mask"] = inside.astype(np.uint8)
    for name, (dtype, shape) in SCHEMA.items():
        if name in arrays:
            continue
        shape = (n,) + tuple({"R": 1}.get(d, d) for d in shape)
        if dtype == "str":
            arrays[name] = [f"{name}-{seed}-{i}" for i in range(n)]
        elif dtype == "bool":
            arrays[name] = rng.random(shape) > 0.5
        else:
            arrays[name] = (rng.random(shape) * 100).astype(dtype)
    return arrays


def make_folder(folder: Path, frames: int, size: int) -> None:
    folder.mkdir(parents=True)
    with stage(f"shard_dataset: writing {frames:,} frames of {size}x{size}", frames, "frame") as progress:
        for k, start in enumerate(range(0, frames, PER_SHARD)):
            n = min(PER_SHARD, frames - start)
            write_shard(folder / f"cup-{k:05d}.h5", frames_arrays(n, size, k), {"renderer": "synthetic", "seed": k})
            progress(n)
    write_manifest(folder)


class PlainH5:
    """The baseline: the same items from plain h5py, nothing verified beyond HDF5's own
    Fletcher-32 (which h5py applies on every read of a checksummed chunk)."""

    def __init__(self, shards, fields):
        import h5py

        self.files = [h5py.File(p, "r") for p in shards]
        self.sets = [{f: (h[f].asstr() if h5py.check_string_dtype(h[f].dtype) else h[f]) for f in fields}
                     for h in self.files]
        self.ends = np.cumsum([int(h.attrs["frames"]) for h in self.files])

    def __len__(self):
        return int(self.ends[-1])

    def __getitem__(self, i):
        shard = int(np.searchsorted(self.ends, i, side="right"))
        j = i - int(self.ends[shard - 1] if shard else 0)
        return {f: ds[j] for f, ds in self.sets[shard].items()}

    def close(self):
        for h in self.files:
            h.close()


def first_item(make) -> tuple:
    """(the dataset, seconds to its first item: ``make()`` and ``[0]``), with nothing verified
    in this process before (as a fresh training run starts)."""
    forget_checks()
    started = time.perf_counter()
    data = make()
    data[0]
    return data, time.perf_counter() - started


def full_pass(label: str, data) -> tuple:
    """(items/s, items per CPU-second of this process) of one pass over every item, in order;
    CPU time is what the load of a shared machine moves less."""
    with stage(f"shard_dataset: {label}", len(data), "frame") as progress:
        t, cpu = time.perf_counter(), time.process_time()
        for i in range(len(data)):
            data[i]
            if i % 1000 == 999:
                progress(1000)
        return len(data) / (time.perf_counter() - t), len(data) / (time.process_time() - cpu)


def run_once(folder: Path, shards) -> dict:
    """Both ways, pass by pass taking turns (verified first, then unverified first), so a load
    that changes during the run falls on both alike."""
    unverified, u_first = first_item(lambda: PlainH5(shards, FIELDS))
    verified, v_first = first_item(lambda: ShardDataset(folder, fields=FIELDS))  # forgets the checks last
    ways = {"verified": verified, "unverified": unverified}
    got = {"verified": {"first": v_first, "passes": [], "cpu": []},
           "unverified": {"first": u_first, "passes": [], "cpu": []}}
    for p, order in enumerate((("verified", "unverified"), ("unverified", "verified"))):
        for label in order:
            wall, cpu = full_pass(f"{label}, pass {p + 1}", ways[label])
            got[label]["passes"].append(wall)
            got[label]["cpu"].append(cpu)
    for data in ways.values():
        data.close()
    return got


def measure(folder: Path, repeat: int) -> None:
    shards = open_folder(folder).shards
    size = sum(p.stat().st_size for p in shards)
    frames = sum(int(e["frames"]) for e in read_manifest(folder)["shards"])
    for path in shards:  # into the page cache, for both ways alike
        path.read_bytes()
    best = {}
    for _ in range(repeat):
        for label, got in run_once(folder, shards).items():
            old = best.get(label)
            best[label] = got if old is None else {"first": min(old["first"], got["first"]),
                                                    "passes": [max(a, b) for a, b in zip(old["passes"], got["passes"])],
                                                    "cpu": [max(a, b) for a, b in zip(old["cpu"], got["cpu"])]}
    v, u = best["verified"], best["unverified"]
    load = ", ".join(f"{x:.2f}" for x in os.getloadavg())
    print(f"{frames:,} frames in {len(shards)} shards, {size / 1e6:,.0f} MB ({size / frames / 1e3:.1f} kB/frame); "
          f"fields {', '.join(FIELDS)}; one frame at a time, in order; best of {repeat}; load average {load}")
    print("| | verified (ShardDataset) | unverified (plain h5py) | verified / unverified |\n|---|---|---|---|")
    print(f"| time to the first item | {v['first']:.3f} s | {u['first']:.3f} s | {v['first'] / u['first']:.1f}x |")
    for key, what in (("passes", "items/s"), ("cpu", "items per CPU-second")):
        for p in range(2):
            a, b = v[key][p], u[key][p]
            print(f"| {what}, pass {p + 1} | {a:,.0f} | {b:,.0f} | {a / b:.2f} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--folder", type=Path, help="read this shard folder; one not there yet is made there "
                        "(and kept) first. Default: made in a temporary folder")
    parser.add_argument("--frames", type=int, default=20_000, help="frames to make (default 20,000)")
    parser.add_argument("--size", type=int, default=128, help="image width and height to make (default 128)")
    parser.add_argument("--repeat", type=int, default=1, help="best of this many runs of each way (default 1)")
    args = parser.parse_args()
    if args.folder is not None:
        if not args.folder.exists():
            make_folder(args.folder, args.frames, args.size)
        measure(args.folder, args.repeat)
        return
    with tempfile.TemporaryDirectory() as tmp:
        make_folder(Path(tmp) / "shards", args.frames, args.size)
        measure(Path(tmp) / "shards", args.repeat)


if __name__ == "__main__":
    main()

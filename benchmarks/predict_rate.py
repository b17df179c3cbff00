"""`spm predict`'s rate at 640x480: per-image time of a saved model on images in memory.

    python benchmarks/predict_rate.py --model MODEL.npz [--model REF.npz] --shards DIR
        [--frames 16] [--repeats 5] [--size 640x480] [--check OUT.json]

Each model is loaded once, the images are decoded once: the first ``--frames`` frames
of DIR's shards (spread over its shards), resized to ``--size`` (bicubic, like
benchmarks/train_scaling.py), then every image goes through the model's
``predict_image`` (what ``spm predict IMAGE`` does after decoding, no mask) ``--repeats``
times after one warm-up pass. Prints, per model, the per-image time (median, mean,
90th percentile, in ms) and the rate (images/s from the median); the target is 100.
``--check OUT.json``: also write every pose, so two versions' outputs can be compared
(``--compare A.json B.json`` prints the largest difference and exits).
Progress on stderr (a bar on a terminal, a line every $SPM_PROGRESS_EVERY s, default 10, elsewhere).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from spm_data.jobs.progress import stage  # noqa: E402
from spm_data.io.shards import read_shard  # noqa: E402
from spm_model.bench.feature_cache import find_shards  # noqa: E402
from spm_model.pipelines.evaluate import load_model  # noqa: E402

TARGET_HZ = 100


def images(shards: Path, frames: int, size: tuple[int, int]) -> list[np.ndarray]:
    """``frames`` (H, W, 3) uint8 images of ``size`` (width, height), decoded once."""
    import cv2

    paths = find_shards(shards)
    per = -(-frames // len(paths))
    out = []
    for path in paths:
        rgb = read_shard(path, ("rgb",), frames=slice(0, per))["rgb"]
        out += [cv2.resize(np.ascontiguousarray(x), size, interpolation=cv2.INTER_CUBIC) for x in rgb]
    return out[:frames]


def time_model(model, imgs: list[np.ndarray], repeats: int, progress=lambda n: None) -> tuple[np.ndarray, list]:
    """Per-image seconds (len(imgs) * repeats,) and the poses of the last pass (None on failure)."""
    def one(rgb):
        try:
            return np.asarray(model.predict_image(rgb)["pose"], dtype=np.float64)
        except Exception as exc:  # noqa: BLE001 - a failed image is reported, not timed out
            return type(exc).__name__

    for x in imgs:  # warm-up: caches, lazy imports
        one(x)
        progress(1)
    times, poses = [], []
    for _ in range(repeats):
        poses = []
        for rgb in imgs:
            t0 = time.perf_counter()
            poses.append(one(rgb))
            times.append(time.perf_counter() - t0)
            progress(1)
    return np.array(times), poses


def compare(a: Path, b: Path) -> None:
    A, B = json.loads(a.read_text()), json.loads(b.read_text())
    for name in A:
        pa, pb = A[name], B[name]
        same_fail = all(isinstance(x, str) == isinstance(y, str) for x, y in zip(pa, pb))
        diff = max((float(np.max(np.abs(np.subtract(x, y)))) for x, y in zip(pa, pb)
                    if not isinstance(x, str) and not isinstance(y, str)), default=0.0)
        print(f"{name}: {len(pa)} images, same failures: {same_fail}, largest pose difference {diff:.3g}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", type=Path, action="append", default=[])
    parser.add_argument("--shards", type=Path)
    parser.add_argument("--frames", type=int, default=16)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--size", default="640x480")
    parser.add_argument("--check", type=Path)
    parser.add_argument("--compare", type=Path, nargs=2)
    args = parser.parse_args()
    if args.compare:
        return compare(*args.compare)
    if not args.model or args.shards is None:
        parser.error("give --model (repeatable) and --shards")
    w, h = (int(v) for v in args.size.split("x"))
    with stage(f"predict_rate: decoding {args.frames} images of {args.shards}"):
        imgs = images(args.shards, args.frames, (w, h))
    print(f"{len(imgs)} images {w}x{h}, {args.repeats} passes each after a warm-up")
    out = {}
    for path in args.model:
        model = load_model(path)
        with stage(f"predict_rate: {path.name}, a warm-up and {args.repeats} passes", len(imgs) * (args.repeats + 1),
                   "image") as progress:
            times, poses = time_model(model, imgs, args.repeats, progress)
        ms = times * 1e3
        med = float(np.median(ms))
        print(f"{path.name} ({type(model).__name__}): per image median {med:.2f} ms, mean {ms.mean():.2f} ms, "
              f"p90 {np.percentile(ms, 90):.2f} ms -> {1e3 / med:.1f} images/s (target {TARGET_HZ})")
        out[path.name] = [p if isinstance(p, str) else p.tolist() for p in poses]
    if args.check:
        args.check.write_text(json.dumps(out))


if __name__ == "__main__":
    main()

"""`spm predict`'s rate at 640x480: per-image time of a saved model on images in memory.

    python benchmarks/predict_rate.py --model MODEL.npz [--model REF.npz] --shards DIR
        [--frames 16] [--repeats 5] [--size 640x480] [--roi object|X,Y,W,H] [--check OUT.json]

Each model is loaded once, the images are decoded once: the first ``--frames`` frames
of DIR's shards (spread over its shards), resized to ``--size`` (bicubic, like
benchmarks/train_scaling.py), then every image goes through the model's
``predict_image`` (what ``spm predict IMAGE`` does after decoding, no mask) ``--repeats``
times after one warm-up pass. ``--roi``: with a region of interest, as ``spm predict --roi``
gives it (its mask built per image, in the timed call): ``object``, each frame's object box
(its mask's, resized with the image) widened by 10% a side; or one fixed ``X,Y,W,H``. Prints, per
model, the per-image time (median, mean, 90th percentile, in ms) and the rate (images/s from
the median), and the process's CPU time per image (what the rate would be with a core to
itself: on a shared machine the wall time includes waiting); the target is 100 images/s, 200
for the cnn model (issue 48: with an ROI).
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
from spm_model.pipelines.predict import roi_mask  # noqa: E402

TARGET_HZ = 100
TARGETS_HZ = {"CNNPose": 200}   # issue 48: spm predict with the cnn model on a 640x480 image with an ROI


def images(shards: Path, frames: int, size: tuple[int, int]) -> tuple[list[np.ndarray], list[tuple]]:
    """``frames`` (H, W, 3) uint8 images of ``size`` (width, height), decoded once, and each one's
    object box (x, y, w, h) in it: its mask's box, resized with it, widened by 10% a side, clipped."""
    import cv2

    paths = find_shards(shards)
    per = -(-frames // len(paths))
    out, boxes = [], []
    for path in paths:
        frame = read_shard(path, ("rgb", "mask"), frames=slice(0, per))
        for rgb, mask in zip(frame["rgb"], frame["mask"]):
            out.append(cv2.resize(np.ascontiguousarray(rgb), size, interpolation=cv2.INTER_CUBIC))
            boxes.append(object_box(cv2.resize((np.asarray(mask) > 0).astype(np.uint8), size,
                                               interpolation=cv2.INTER_NEAREST)))
    return out[:frames], boxes[:frames]


def object_box(mask: np.ndarray, margin: float = 0.1) -> tuple:
    """(x, y, w, h) of the mask's non-zero pixels widened by ``margin`` of its size a side, inside the
    image; the whole image when the mask is empty."""
    h, w = mask.shape
    ys, xs = np.nonzero(mask)
    if not len(xs):
        return 0, 0, w, h
    dx, dy = int(margin * (xs.max() - xs.min() + 1)), int(margin * (ys.max() - ys.min() + 1))
    x0, y0 = max(0, xs.min() - dx), max(0, ys.min() - dy)
    x1, y1 = min(w, xs.max() + 1 + dx), min(h, ys.max() + 1 + dy)
    return int(x0), int(y0), int(x1 - x0), int(y1 - y0)


def parse_roi(text: str | None):
    """--roi: None (no ROI), "object" (each image's object box) or a fixed (x, y, w, h)."""
    if text is None or text == "object":
        return text
    return tuple(int(v) for v in text.split(","))


def time_model(model, imgs: list[np.ndarray], repeats: int, progress=lambda n: None,
               rois=None) -> tuple[np.ndarray, list, float]:
    """Per-image seconds (len(imgs) * repeats,), the poses of the last pass (None on failure) and
    the process's CPU seconds per image over the timed passes (on a shared machine the wall time
    includes waiting for a core; the CPU time does not). rois: None, or one (x, y, w, h) per image,
    given as spm predict --roi gives it (roi_mask, timed)."""
    def one(i):
        try:
            mask = None if rois is None else roi_mask(rois[i], imgs[i].shape[1], imgs[i].shape[0])
            return np.asarray(model.predict_image(imgs[i], mask)["pose"], dtype=np.float64)
        except Exception as exc:  # noqa: BLE001 - a failed image is reported, not timed out
            return type(exc).__name__

    for i in range(len(imgs)):  # warm-up: caches, lazy imports
        one(i)
        progress(1)
    times, poses, cpu = [], [], time.process_time()
    for _ in range(repeats):
        poses = []
        for i in range(len(imgs)):
            t0 = time.perf_counter()
            poses.append(one(i))
            times.append(time.perf_counter() - t0)
            progress(1)
    return np.array(times), poses, (time.process_time() - cpu) / max(1, len(times))


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
    parser.add_argument("--roi", default=None, metavar="object|X,Y,W,H",
                        help="predict with a region of interest: each image's object box, or a fixed one")
    parser.add_argument("--check", type=Path)
    parser.add_argument("--compare", type=Path, nargs=2)
    args = parser.parse_args()
    if args.compare:
        return compare(*args.compare)
    if not args.model or args.shards is None:
        parser.error("give --model (repeatable) and --shards")
    w, h = (int(v) for v in args.size.split("x"))
    with stage(f"predict_rate: decoding {args.frames} images of {args.shards}"):
        imgs, boxes = images(args.shards, args.frames, (w, h))
    roi = parse_roi(args.roi)
    rois = None if roi is None else boxes if roi == "object" else [roi] * len(imgs)
    sides = "" if rois is None else (f", ROI {args.roi} (median {int(np.median([b[2] for b in rois]))} x "
                                     f"{int(np.median([b[3] for b in rois]))} px)")
    print(f"{len(imgs)} images {w}x{h}{sides}, {args.repeats} passes each after a warm-up")
    out = {}
    for path in args.model:
        model = load_model(path)
        with stage(f"predict_rate: {path.name}, a warm-up and {args.repeats} passes", len(imgs) * (args.repeats + 1),
                   "image") as progress:
            times, poses, cpu = time_model(model, imgs, args.repeats, progress, rois)
        ms = times * 1e3
        med = float(np.median(ms))
        target = TARGETS_HZ.get(type(model).__name__, TARGET_HZ)
        print(f"{path.name} ({type(model).__name__}): per image median {med:.2f} ms, mean {ms.mean():.2f} ms, "
              f"p90 {np.percentile(ms, 90):.2f} ms -> {1e3 / med:.1f} images/s (target {target}); CPU time "
              f"{cpu * 1e3:.2f} ms per image -> {1 / cpu:.1f} images/s on a core of its own")
        out[path.name] = [p if isinstance(p, str) else p.tolist() for p in poses]
    if args.check:
        args.check.write_text(json.dumps(out))


if __name__ == "__main__":
    main()

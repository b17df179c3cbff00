"""How far a frame's SPM query vector is from its own training vector, against other frames'.

    python benchmarks/spm_vector_distance.py SHARDS [--seed 0] [--snapshot docs/results/measures/spm-vectors.json]

SPM trains on a frame's *training* vector (the keypoints that are RANSAC inliers against its
5-degree path neighbours) and is asked with its *query* vector (every keypoint in the mask)
(docs/method.md, spm_model/spm/features.py). For every frame with both vectors (features
cached or extracted by the library call `spm train` uses), this prints the median L2 distance
between its query vector and its own training vector, and between its query vector and the
training vector of a random other frame of its class (seeded), and the same for the training
vectors of the frame and that random frame: when the first is about the second, a query is as
unlike its own training vector as another view's, and a regressor from training vectors cannot
place it. With --snapshot it writes those figures and how they were made (a ``made`` block:
date, command, wall_s, machine; scripts/results_doc.py) for docs/results.md.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from spm_data.errors import SpmError  # noqa: E402
from spm_model.bench.feature_cache import load_features  # noqa: E402


def distances(train, query, classes, seed: int = 0) -> dict:
    """Median L2 distances over the frames with both vectors finite: ``own`` (query to its own
    training vector), ``other`` (query to a random other frame's training vector of its class),
    ``train_other`` (training vector to that frame's); ``frames`` counted, per class too."""
    train, query, classes = np.asarray(train, float), np.asarray(query, float), np.asarray(classes)
    ok = np.isfinite(train).all(axis=1) & np.isfinite(query).all(axis=1)
    rng = np.random.default_rng(seed)
    own, other, train_other, names = [], [], [], []
    for name in sorted(set(classes[ok].tolist())):
        rows = np.flatnonzero(ok & (classes == name))
        if len(rows) < 2:
            continue
        # another frame of the class for each: a random shift of the row order, never zero
        partner = rows[(np.arange(len(rows)) + rng.integers(1, len(rows), len(rows))) % len(rows)]
        own.append(np.linalg.norm(query[rows] - train[rows], axis=1))
        other.append(np.linalg.norm(query[rows] - train[partner], axis=1))
        train_other.append(np.linalg.norm(train[rows] - train[partner], axis=1))
        names.append(name)
    per_class = {n: {"frames": len(o), "own": float(np.median(o)), "other": float(np.median(r))}
                 for n, o, r in zip(names, own, other)}
    if not own:
        return {"frames": 0, "own": None, "other": None, "train_other": None, "classes": {}}
    own, other, train_other = (np.concatenate(v) for v in (own, other, train_other))
    return {"frames": int(len(own)), "own": float(np.median(own)), "other": float(np.median(other)),
            "train_other": float(np.median(train_other)), "classes": per_class}


def _made_block(command: str, wall_s: float) -> dict:
    spec = importlib.util.spec_from_file_location("results_doc", ROOT / "scripts" / "results_doc.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.made_block(command, wall_s)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("shards", type=Path)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--snapshot", type=Path, help="write the figures and how they were made to this JSON")
    args = parser.parse_args(argv)
    start = time.monotonic()
    try:
        table = load_features(args.shards)
    except SpmError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    found = distances(table.train_vector, table.query_vector, table.class_name, args.seed)
    found["all_frames"] = len(table)
    wall = time.monotonic() - start
    print(f"{found['frames']:,} of {len(table):,} frames with both vectors: median L2 query to own training "
          f"vector {found['own']:.3f}, to another frame's of its class {found['other']:.3f} (training to training "
          f"{found['train_other']:.3f}); {wall:.1f} s")
    if args.snapshot:
        command = " ".join(["python benchmarks/spm_vector_distance.py", str(args.shards), "--seed", str(args.seed)])
        snap = {"summary": found, "made": _made_block(command, wall)}
        args.snapshot.parent.mkdir(parents=True, exist_ok=True)
        tmp = args.snapshot.with_name(f".{args.snapshot.name}.partial")
        tmp.write_text(json.dumps(snap, indent=1) + "\n")
        tmp.replace(args.snapshot)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

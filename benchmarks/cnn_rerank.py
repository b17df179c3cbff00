"""Choosing the cnn method's ``rerank`` and ``hog_weight`` on held-out TRAINING frames (never a benchmark's
test frames): for each protocol, the benchmark's first split (seed 0, as `spm train --runs 1` draws it)
gives the training rows (unoccluded, as the benchmark trains); those are split again by the same protocol
(seed 100) into inner training and validation frames; one CNNPose (default budget, seed 0) is fitted on the
inner training frames and the validation frames are predicted for a grid of (rerank, hog_weight): the
network is trained once, only the retrieval changes. Prints and writes ±5° % (and up to symmetry) per cell.

    python benchmarks/cnn_rerank.py SHARDS --protocols views,instances [--bins 256] --out rerank.json
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from spm_model.base.frames import Frames, read_camera_frames  # noqa: E402
from spm_model.bench.feature_cache import load_features  # noqa: E402
from spm_model.bench.metrics import tolerance_rate  # noqa: E402
from spm_model.bench.protocols import splits, training_rows  # noqa: E402
from spm_model.bench.scoring import frame_errors  # noqa: E402
from spm_model.bench.surface_metrics import mesh_keys  # noqa: E402
from spm_model.bench.symmetry_errors import instance_symmetries  # noqa: E402
from spm_model.methods.cnn import CNNPose, frame_crops  # noqa: E402

# rerank -1: every training frame scored (the default); k >= 2: the k nearest embeddings re-ranked; 0: none.
GRID = ([(0, 1.0)] + [(k, w) for k in (16, 64) for w in (2.0, 8.0, 1000.0)]
        + [(-1, w) for w in (1.0, 2.0, 4.0, 8.0, 16.0, 32.0, 1000.0)])


def inner_split(table, protocol: str) -> tuple[np.ndarray, np.ndarray]:
    """(inner training rows, validation rows): the first split's training rows, split again."""
    _, train, _ = splits(table, protocol, seed=0)[0]
    train = training_rows(table, train, False)
    _, inner, held = splits(table.subset(train), protocol, seed=100)[0]
    return train[inner], train[held]


def sweep(table, protocol: str, keys: list, symmetries: list, bins: int = 256) -> dict:
    """{"rerank/weight": (±5° %, ±5° sym. %)} on one protocol's validation frames, with the fit's cost."""
    inner, held = inner_split(table, protocol)
    start = time.perf_counter()
    model = CNNPose(seed=0, bins=bins, rerank=-1).fit(Frames(table, inner), table.pose[inner])
    print(f"{protocol}: {len(inner)} inner training frames, {len(held)} validation frames, fit "
          f"{time.perf_counter() - start:.0f} s", flush=True)
    crops, geometry = frame_crops(read_camera_frames(table, held))
    K = np.asarray(table.K[held], np.float64)
    rows = {}
    for rerank, weight in GRID:
        model.rerank, model.hog_weight = rerank, weight
        errors = frame_errors(table, held, model.predict_crops(crops, geometry, K), keys, symmetries)
        rows[f"{rerank}/{weight}"] = tuple(None if r is None else round(r, 1) for r in (   # sym.: None without meshes
            tolerance_rate(errors["rotation_max"]), tolerance_rate(errors["rotation_max_sym"])))
        print(f"{protocol} rerank {rerank} weight {weight}: ±5° {rows[f'{rerank}/{weight}'][0]}%, "
              f"sym. {rows[f'{rerank}/{weight}'][1]}%", flush=True)
    return {"inner": len(inner), "validation": len(held), "cells": rows}


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("shards")
    parser.add_argument("--protocols", default="views,instances")
    parser.add_argument("--bins", type=int, default=256, help="the cnn's view bins (default 256, its default)")
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args(argv)
    table = load_features(args.shards)
    keys = mesh_keys(table.shard, table.instance_id)
    symmetries = instance_symmetries(keys)
    out = {"date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()), "machine": platform.node(),
           "cpus": os.cpu_count(), "load": os.getloadavg(), "shards": str(args.shards),
           "bins": args.bins,
           "protocols": {p: sweep(table, p, keys, symmetries, args.bins) for p in args.protocols.split(",")}}
    args.out.write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()

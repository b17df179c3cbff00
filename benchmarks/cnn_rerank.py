"""Choosing the cnn method's ``rerank`` and ``hog_weight`` on held-out TRAINING frames (never a benchmark's
test frames): for each protocol, the benchmark's first split (seed 0, as `spm train --runs 1` draws it)
gives the training rows (unoccluded, as the benchmark trains); those are split again by the same protocol
(seed 100) into inner training and validation frames (its first --folds splits: instances and loco have
one per instance or class); one CNNPose (default budget, seed 0, --param settings) is fitted on each
split's inner training frames and its validation frames are predicted for a grid of (rerank, hog_weight):
one network per split, only the retrieval changes. Prints and writes ±5° % (and up to symmetry) per cell,
pooled over the splits.

    python benchmarks/cnn_rerank.py SHARDS --protocols views,instances [--bins 256] [--param width=32 ...]
        [--grid all|short] [--folds N] --out rerank.json
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
SHORT = [(0, 1.0), (16, 2.0), (64, 8.0), (-1, 4.0), (-1, 8.0), (-1, 16.0), (-1, 1000.0)]


def inner_splits(table, protocol: str, folds: int = 1) -> list[tuple[np.ndarray, np.ndarray]]:
    """[(inner training rows, validation rows)]: the first split's training rows, split again by the
    same protocol; its first ``folds`` splits (``instances`` and ``loco`` have one per instance or class)."""
    _, train, _ = splits(table, protocol, seed=0)[0]
    train = training_rows(table, train, False)
    return [(train[inner], train[held]) for _, inner, held in splits(table.subset(train), protocol, seed=100)[:folds]]


def sweep(table, protocol: str, keys: list, symmetries: list, params: dict, grid: list = GRID,
          folds: int = 1) -> dict:
    """{"rerank/weight": (±5° %, ±5° sym. %)} on one protocol's validation frames, pooled over ``folds``
    inner splits (a network fitted on each), with the fits' cost; ``params``: CNNPose parameters besides
    the seed (0)."""
    errors, sizes, fit_s = {cell: [] for cell in grid}, [], 0.0
    for inner, held in inner_splits(table, protocol, folds):
        start = time.perf_counter()
        model = CNNPose(**{**params, "seed": 0, "rerank": -1}).fit(Frames(table, inner), table.pose[inner])
        fit_s += time.perf_counter() - start
        sizes.append((len(inner), len(held)))
        print(f"{protocol}: {len(inner)} inner training frames, {len(held)} validation frames, fit "
              f"{time.perf_counter() - start:.0f} s", flush=True)
        crops, geometry = frame_crops(read_camera_frames(table, held))
        K = np.asarray(table.K[held], np.float64)
        for rerank, weight in grid:
            model.rerank, model.hog_weight = rerank, weight
            errors[rerank, weight].append(frame_errors(table, held, model.predict_crops(crops, geometry, K), keys,
                                                       symmetries))
    rows = {}
    for (rerank, weight), parts in errors.items():
        rates = [tolerance_rate(np.concatenate([np.asarray(p[key], float) for p in parts]))
                 if all(p[key] is not None for p in parts) else None for key in ("rotation_max", "rotation_max_sym")]
        rows[f"{rerank}/{weight}"] = tuple(None if r is None else round(r, 1) for r in rates)  # sym.: None, no mesh
        print(f"{protocol} rerank {rerank} weight {weight}: ±5° {rows[f'{rerank}/{weight}'][0]}%, "
              f"sym. {rows[f'{rerank}/{weight}'][1]}%", flush=True)
    return {"folds": sizes, "inner": sum(a for a, _ in sizes), "validation": sum(b for _, b in sizes),
            "fit_s": round(fit_s, 1), "cells": rows}


def parameters(pairs: list[str], bins: int) -> dict:
    """--param KEY=VALUE pairs (JSON values as such: 32, 0.5, true; anything else as text: cpu) and --bins
    -> CNNPose parameters."""
    out = {"bins": bins}
    for pair in pairs:
        key, _, value = pair.partition("=")
        try:
            out[key] = json.loads(value)
        except json.JSONDecodeError:
            out[key] = value
    return out


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("shards")
    parser.add_argument("--protocols", default="views,instances")
    parser.add_argument("--bins", type=int, default=256, help="the cnn's view bins (default 256, its default)")
    parser.add_argument("--param", action="append", default=[], metavar="KEY=VALUE",
                        help="another CNNPose parameter for the fit, e.g. width=32 (repeatable)")
    parser.add_argument("--grid", choices=("all", "short"), default="all",
                        help="short: embedding alone; shortlists 16 (weight 2), 64 (8); every frame, 4, 8, 16, 1000")
    parser.add_argument("--folds", type=int, default=1,
                        help="inner splits pooled per protocol (instances, loco: one per instance or class; default 1)")
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args(argv)
    params = parameters(args.param, args.bins)
    grid = GRID if args.grid == "all" else SHORT
    table = load_features(args.shards)
    keys = mesh_keys(table.shard, table.instance_id)
    symmetries = instance_symmetries(keys)
    out = {"date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()), "machine": platform.node(),
           "cpus": os.cpu_count(), "load": os.getloadavg(), "shards": str(args.shards),
           "params": params,
           "protocols": {p: sweep(table, p, keys, symmetries, params, grid, args.folds)
                         for p in args.protocols.split(",")}}
    args.out.write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()

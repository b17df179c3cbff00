"""What a method that returns one of the test object's own training views can reach at best: for each
run's split (as `spm train --protocol P --runs R` draws them: seeds 0 .. R-1), the ±5° of the oracle
that picks, for every test frame, the training frame of the same object (class and instance) whose
label is nearest by the benchmark's own ±5° measure (spm_model/bench/metrics.py ``pose_errors``,
measured angles only). A test frame whose object has no training view within ±5° (under ``views``,
both turntable neighbours held out too) fails for any such method; interpolating between views is the
only way past this ceiling. Prints one line per run and the mean.

    python benchmarks/retrieval_ceiling.py SHARDS [--protocol views] [--runs 3]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from spm_model.bench.feature_cache import load_features  # noqa: E402
from spm_model.bench.metrics import pose_errors, tolerance_rate  # noqa: E402
from spm_model.bench.protocols import splits, training_rows  # noqa: E402


def nearest_own_view_errors(table, train: np.ndarray, test: np.ndarray) -> np.ndarray:
    """(len(test),) the smallest ``rotation_max`` (degrees) over the training frames of each test frame's
    object; inf where the object has no training frame."""
    obj = np.char.add(np.asarray(table.class_name, str), np.char.add("/", np.asarray(table.instance_id, str)))
    best = np.full(len(test), np.inf)
    for k, i in enumerate(test):
        own = train[obj[train] == obj[i]]
        if len(own):
            truth = np.repeat(table.pose[i][None], len(own), axis=0)
            measured = np.repeat(table.label_measured[i][None], len(own), axis=0)
            best[k] = np.nanmin(pose_errors(table.pose[own], truth, measured)["rotation_max"])
    return best


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("shards")
    parser.add_argument("--protocol", default="views", choices=("views", "interleaved", "offgrid"))
    parser.add_argument("--runs", type=int, default=3)
    args = parser.parse_args(argv)
    table = load_features(args.shards)
    rates = []
    for run in range(args.runs):
        for _, train, test in splits(table, args.protocol, seed=run):
            rate = tolerance_rate(nearest_own_view_errors(table, training_rows(table, train, False), test))
            rates.append(rate)
            print(f"run {run + 1}: {len(test)} test frames, {100 - rate:.1f}% without a training view of their "
                  f"object within ±5°: ceiling {rate:.1f}%", flush=True)
    print(f"mean ceiling over {len(rates)} run(s): {np.mean(rates):.1f}%")


if __name__ == "__main__":
    main()

"""The library call behind ``spm train``: features, the protocol, final models and the report."""

from __future__ import annotations

from dataclasses import asdict
from pathlib import Path

import numpy as np

from spm_data.errors import ModelError
from spm_data.io.outputs import removing_created
from spm_model.bench.feature_cache import FeatureTable, load_features, offgrid_table
from spm_model.bench.protocols import evaluate
from spm_model.bench.report import check_report_folder, summary_text, write_error, write_report
from spm_model.methods.registry import load_estimator_class
from spm_model.methods.spm_pose import MIN_TRAIN_FRAMES
from spm_model.spm.features import FeatureConfig


def check_classes(table: FeatureTable) -> dict:
    """Frames with training features per class; ModelError for a class with too few."""
    counts = {}
    usable = np.isfinite(table.train_vector).all(axis=1)
    for c in sorted(set(table.class_name.tolist())):
        counts[c] = int(usable[table.class_name == c].sum())
        if counts[c] < MIN_TRAIN_FRAMES:
            total = int((table.class_name == c).sum())
            raise ModelError(f"class {c!r} has {counts[c]} of {total} frames with features (need at least "
                             f"{MIN_TRAIN_FRAMES}); render more views or larger images, or leave its shards out")
    return counts


def load_estimators(specs) -> dict:
    """{name: class} of ``--estimator MODULE:CLASS`` values (name: CLASS, or MODULE:CLASS if two share it)."""
    classes = {spec: load_estimator_class(spec) for spec in dict.fromkeys(specs or ())}
    short = [spec.split(":")[1] for spec in classes]
    return {(spec.split(":")[1] if short.count(spec.split(":")[1]) == 1 else spec): cls
            for spec, cls in classes.items()}


def train(shards, report_dir=None, *, protocol: str | None = None, runs: int = 3,
          features: FeatureConfig = FeatureConfig(), model_params: dict | None = None, progress=None,
          log=lambda message: None, command: str = "spm train", executor=None, estimators=(),
          allow_partial: bool = False, test=None, train_occluded: bool | None = None,
          builtins=None) -> dict:
    """Features of every shard under ``shards`` (cached), the evaluation protocol
    over ``runs`` seeds for every built-in method (``builtins``: their names, default
    all) and each ``estimators`` entry ('MODULE:CLASS'), final models on every
    training frame, and the report files. ``test``: the test folder of the offgrid
    protocol (given alone, it selects offgrid); ``train_occluded``: see
    spm_model/bench/protocols.py.
    Returns {"report": folder, "model", "reference_model": paths, "summary", "evaluation", "text"}."""
    if runs < 1:
        raise ModelError(f"--runs must be at least 1, got {runs}")
    if test is not None and protocol not in ("offgrid", None):
        raise ModelError(f"--test goes with --protocol offgrid, got --protocol {protocol}; leave --protocol out "
                         "or give offgrid")
    protocol = "offgrid" if test is not None else (protocol or "loco")
    out = check_report_folder(report_dir if report_dir else Path(shards) / "report")  # before any work
    plugins = load_estimators(estimators)
    table = load_features(shards, features, progress=progress, executor=executor,
                          allow_partial=allow_partial)
    if test is not None:
        table = offgrid_table(table, load_features(test, features, progress=progress, executor=executor,
                                                   allow_partial=allow_partial))
    counts = check_classes(table)
    log(f"{len(table)} frames, {len(counts)} classes: " + ", ".join(f"{c} {n}" for c, n in counts.items())
        + " (frames with training features)")
    alone = int((table.train_neighbours == 0).sum())
    if alone:
        log(f"{alone} frames have no 5-degree path neighbour in their shard; their training features "
            "use every keypoint in the mask (docs/method.md)")
    model_params = dict(model_params or {}, features=features)
    source = (str(shards), None if test is None else str(test), features, allow_partial)
    evaluation = evaluate(table, protocol, runs, model_params, estimators=plugins, report=log, builtins=builtins,
                          train_occluded=train_occluded, executor=executor, source=source, final=True)
    model, reference, train_features = evaluation.pop("final_models")
    context = {"command": command, "shards": str(shards), **({"test": str(test)} if test is not None else {}),
               "frames": len(table), "train_features": int(train_features),
               "query_features": int(np.isfinite(table.query_vector).all(axis=1).sum()),
               "without_path_neighbour": int((table.train_neighbours == 0).sum()),
               "frames_per_class": {c: int((table.class_name == c).sum()) for c in counts},
               "model_params": {k: v for k, v in model_params.items() if k != "features"},
               "features": asdict(features), "estimators": {name: f"{cls.__module__}:{cls.__qualname__}"
                                                            for name, cls in plugins.items()}}
    try:
        with removing_created(out / "model.npz"):  # a report folder this run made goes again on failure
            out.mkdir(parents=True, exist_ok=True)
            model_path = model.save(out / "model.npz")
            reference_path = reference.save(out / "reference-model.npz")
            summary = write_report(evaluation, context, out)
    except OSError as exc:
        raise write_error(out, exc) from None
    return {"report": out, "model": model_path, "reference_model": reference_path, "summary": summary,
            "evaluation": evaluation, "text": summary_text(summary)}



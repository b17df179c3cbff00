"""The library call behind ``spm train``: features, the protocol, final models and the report."""

from __future__ import annotations

from dataclasses import asdict
from pathlib import Path

import numpy as np

from spm_data.errors import ShardError, SpmError
from spm_model.errors import ModelError
from spm_data.io.folders import find_folders
from spm_data.io.locking import OutputLock
from spm_data.io.outputs import removing_created
from spm_data.io.shards import MANIFEST, list_shards, read_attrs, read_manifest
from spm_model.bench.feature_cache import FeatureTable, load_features, offgrid_table, progress_phase
from spm_model.bench.final_models import save_final_models, training_costs
from spm_model.bench.isolation import DEFAULT_TIMEOUT
from spm_model.bench.plugin_refs import describe
from spm_model.bench.protocols import evaluate, final_rows
from spm_model.bench.report import (check_report_folder, declined_everywhere, summary_text, write_error,
                                    write_report)
from spm_model.methods.cnn import device_note
from spm_model.methods.registry import SAVED_MODELS, check_method_names
from spm_model.spm.features import FeatureConfig


def class_counts(table: FeatureTable) -> dict:
    """{class: frames} (the run's data line, whose counts add up to the frames)."""
    return {c: int((table.class_name == c).sum()) for c in sorted(set(table.class_name.tolist()))}


def data_line(table: FeatureTable, counts: dict) -> str:
    """"N frames, K classes: a n_a, b n_b; M with SPM's training features" (SPM's own need is checked
    by the benchmark, for SPM alone)."""
    usable = int(np.isfinite(table.train_vector).all(axis=1).sum())
    return (f"{len(table)} frames, {len(counts)} class{'es' if len(counts) != 1 else ''}: "
            + ", ".join(f"{c} {n}" for c, n in counts.items())
            + f"; {'all' if usable == len(table) else usable} with SPM's training features")


def length_unit(*folders) -> str:
    """"m", or "capture unit" where a shard under ``folders`` was imported without a metric scale
    (import nerf without --scale: its lengths are the capture's world units, taken as metres)."""
    units = {str(read_attrs(p).get("length_unit", "m")) for f in folders if f is not None
             for folder in find_folders(f) for p in list_shards(folder)}
    return "m" if units <= {"m"} else "capture unit"


def listed_classes(shards) -> set | None:
    """The classes the manifests under ``shards`` list (read before any feature is extracted);
    None where a folder has no manifest to tell (a single shard, an unfinished run)."""
    classes = set()
    for folder in find_folders(shards):
        if not (folder / MANIFEST).is_file():
            return None
        try:
            manifest = read_manifest(folder)
        except SpmError:
            return None
        for entry in manifest["shards"]:
            classes.update(entry.get("classes") or {})
    return classes


def choose_protocol(protocol: str | None, test, shards, log) -> str:
    """The protocol to run: offgrid with --test; else the one asked for; else loco where the data has
    two classes or more, and views (said in one line) where it has one. loco asked for on one class
    is refused before any feature is extracted (where the manifests tell)."""
    if test is not None:
        return "offgrid"
    classes = listed_classes(shards) if protocol in (None, "loco") else None
    if protocol is None and classes is not None and len(classes) == 1:
        log(f"one class ({next(iter(classes))}): leave-one-class-out cannot run, so the views protocol does "
            "(new views of seen objects); frames on a camera path (a capture, a turntable) test more views "
            "with --protocol interleaved")
        return "views"
    if protocol == "loco" and classes is not None and len(classes) < 2:
        raise ModelError(f"leave-one-class-out needs at least 2 classes, found {sorted(classes)}; add shards of "
                         "other classes or use --protocol views (or interleaved)")
    return protocol or "loco"


def load_estimators(specs, timeout: float | None = DEFAULT_TIMEOUT) -> dict:
    """{name: PluginRef} of ``--estimator MODULE:CLASS`` values (name: CLASS, or MODULE:CLASS if two
    share it), each imported in a process of its own, never this one (spm_model/bench/plugin_refs.py);
    one that cannot be imported, or whose NEEDS is not a Needs, is refused here, before any work."""
    refs = describe(specs, timeout)
    short = [spec.split(":")[1] for spec in refs]
    return {(spec.split(":")[1] if short.count(spec.split(":")[1]) == 1 else spec): ref
            for spec, ref in refs.items()}


def train(shards, report_dir=None, *, protocol: str | None = None, runs: int = 3,
          features: FeatureConfig = FeatureConfig(), model_params: dict | None = None, progress=None,
          log=lambda message: None, command: str = "spm train", executor=None, estimators=(),
          allow_partial: bool = False, test=None, train_occluded: bool | None = None,
          builtins=None, bop=None, timeout: float | None = DEFAULT_TIMEOUT) -> dict:
    """Features of every shard under ``shards`` (cached), the evaluation protocol
    over ``runs`` seeds for every built-in method (``builtins``: their names, default
    all) and each ``estimators`` entry ('MODULE:CLASS'), final models on every
    training frame, and the report files. ``test``: the test folder of the offgrid
    protocol (given alone, it selects offgrid); ``train_occluded``: see
    spm_model/bench/protocols.py. progress: a callable taking count deltas, told each step
    (feature_cache.progress_phase): the features (load_features), "fitting" and "scoring"
    (protocols.evaluate), "report". bop: a BopOutput (bop_output.py): also write the first run's
    estimates as BOP results files (its ``bop_results``). timeout: seconds a plug-in's call (construct
    and fit, or one predict) may take before the plug-in is declined (None: no limit). model_params:
    SPM's parameters, and as "cnn" the cnn method's ({"device": "cuda"}: spm train --device).
    Returns {"report": folder, "model_files": {method: path of each model written}, "models": {method:
    "written" or {"declined": why}}, "summary", "evaluation", "text", "bop_results"}."""
    if runs < 1:
        raise ModelError(f"--runs must be at least 1, got {runs}")
    builtins = check_method_names(builtins)   # before any work: an unknown name is one line, not no method
    if test is not None and protocol not in ("offgrid", None):
        raise ModelError(f"--test goes with --protocol offgrid, got --protocol {protocol}; leave --protocol out "
                         "or give offgrid")
    for folder in (shards, test):
        if folder is not None and not Path(folder).exists():   # before a report folder is made inside it
            raise ShardError(f"no such folder: {folder}")
    out = check_report_folder(report_dir if report_dir else Path(shards) / "report")  # before any work
    plugins = load_estimators(estimators, timeout)
    _cnn_device(model_params, builtins)   # before any work: a device torch cannot use is one line
    if bop is not None:
        bop.check(shards, test, allow_partial=allow_partial)
    # The report folder is locked for the whole run as a shard folder is: a second train (or
    # fig5.py) into it is refused with the first one's pid and host, not raced; a folder this
    # run made goes again if the run fails or is interrupted.
    with removing_created(out / "model.npz"):
        try:
            out.mkdir(parents=True, exist_ok=True)
            lock = OutputLock(out)
            lock.acquire()
        except OSError as exc:
            raise write_error(out, exc) from None
        try:
            return _train(shards, out, protocol, runs, features, model_params, progress, log, command,
                          executor, plugins, allow_partial, test, train_occluded, builtins, bop, timeout)
        finally:
            lock.release()


def _train(shards, out, protocol, runs, features, model_params, progress, log, command, executor, plugins,
           allow_partial, test, train_occluded, builtins, bop=None, timeout=DEFAULT_TIMEOUT) -> dict:
    """train()'s work, in its locked report folder ``out``."""
    protocol = choose_protocol(protocol, test, shards, log)
    table = load_features(shards, features, progress=progress, executor=executor,
                          allow_partial=allow_partial)
    if test is not None:
        table = offgrid_table(table, load_features(test, features, progress=progress, executor=executor,
                                                   allow_partial=allow_partial, what="test features"))
    counts = class_counts(table)
    log(data_line(table, counts))
    unit = length_unit(shards, test)
    if unit != "m":
        log("lengths are the capture's world units (imported without --scale): the report's mm are thousandths "
            "of that unit")
    if (table.train_neighbours == 0).any():
        log(alone_line(table))
    note = _cnn_device(model_params, builtins)   # said once the data is (a refusal before stays one line)
    if note:
        log(note)
    model_params = dict(model_params or {}, features=features)
    source = (str(shards), None if test is None else str(test), features, allow_partial)
    evaluation = evaluate(table, protocol, runs, model_params, estimators=plugins, report=log, builtins=builtins,
                          train_occluded=train_occluded, executor=executor, source=source, final=True,
                          progress=progress, timeout=timeout)
    fitted, final_declined = evaluation.pop("final_models")
    check_some_method_ran(evaluation)
    rows = final_rows(table, evaluation["train_occluded"])
    train_features = np.isfinite(table.train_vector[rows]).all(axis=1).sum()   # the final SPM model's frames
    asked = [m for m in SAVED_MODELS if _asked(m, builtins)]   # a model only of a method asked for
    models = {m: "written" if fitted.get(m) is not None else {"declined": final_declined.get(m, "")}
              for m in asked}
    costs = training_costs(fitted)
    context = {"command": command, "shards": str(shards), **({"test": str(test)} if test is not None else {}),
               "frames": len(table), "train_features": int(train_features),
               "query_features": int(np.isfinite(table.query_vector).all(axis=1).sum()),
               "without_path_neighbour": int((table.train_neighbours == 0).sum()),
               "frames_per_class": {c: int((table.class_name == c).sum()) for c in counts},
               "model_params": {k: v for k, v in model_params.items() if k != "features"},
               "features": asdict(features), "estimators": {name: getattr(cls, "spec", None) or
                                                            f"{cls.__module__}:{cls.__qualname__}"
                                                            for name, cls in plugins.items()},
               "models": models, **({"length_unit": unit} if unit != "m" else {}),
               **({"training": costs} if costs else {})}
    progress_phase(progress, "report", None, None)
    try:
        model_files = save_final_models(fitted, out)
    except OSError as exc:
        raise write_error(out, exc) from None
    summary = write_report(evaluation, context, out)
    written = [] if bop is None else _bop_results(bop, table, evaluation["protocol"], model_params, builtins,
                                                   plugins, train_occluded, test or shards, allow_partial, timeout)
    return {"report": out, "model_files": model_files, "summary": summary, "evaluation": evaluation,
            "text": summary_text(summary), "models": models, "bop_results": written}


def alone_line(table: FeatureTable) -> str:
    """The note on the frames without a 5-degree path neighbour in their shard: as expected (not a
    warning) where every one of them is in a shard rendered with --limit, which spreads the frames
    over the camera path so that no two are neighbours."""
    alone = table.train_neighbours == 0
    limited = all(_frame_limit(shard) for shard in set(np.asarray(table.shard)[alone].tolist()))
    why = (", as expected: `spm-data render --limit` spreads a shard's frames over its camera path" if limited
           else "")
    return (f"{int(alone.sum())} frames have no 5-degree path neighbour in their shard{why}; their training "
            "features use every keypoint in the mask (docs/method.md)")


def _frame_limit(shard) -> int:
    """The --limit the shard was rendered with (0: none, or not a render, or unreadable now)."""
    try:
        return int(read_attrs(shard).get("frame_limit", 0))
    except (SpmError, OSError, ValueError):
        return 0


def _bop_results(bop, table, protocol, model_params, builtins, plugins, train_occluded, folder, allow_partial,
                 timeout):
    """The first run's estimates of every method as BOP results files (bop_output.py)."""
    from spm_model.pipelines.bop_output import first_run_predictions

    predictions = first_run_predictions(table, protocol, model_params, builtins, plugins, train_occluded, timeout)
    return bop.write(folder, table, predictions, allow_partial)


def _cnn_device(model_params, builtins) -> str | None:
    """Where the cnn method will run, in one line (cnn.device_note), when it is asked for; ModelError
    for a device torch cannot use, so it is refused before any work, not declined."""
    device = ((model_params or {}).get("cnn") or {}).get("device", "auto")
    return device_note(device) if _asked("cnn", builtins) else None


def _asked(method: str, builtins) -> bool:
    return builtins is None or method in builtins


def check_some_method_ran(evaluation: dict) -> None:
    """ModelError (one line) when every method asked for, chance aside, declined in every split:
    nothing to report (asking for chance alone is not refused)."""
    gone = declined_everywhere(evaluation)
    asked = [m for m in evaluation["methods"] if m != "chance"]
    if asked and all(m in gone for m in asked):
        reasons = "; ".join(f"{m}: {_short(gone[m])}" for m in asked)
        raise ModelError(f"no method could run on this data (chance aside): {reasons}")


def _short(text: str, most: int = 160) -> str:
    return text if len(text) <= most else text[: most - 1] + "…"



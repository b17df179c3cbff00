"""Protocols and repeated runs: every method (spm_model/methods/registry.py, plus any
``--estimator``) on the same splits.

- ``loco`` (the paper's): for each class, train on the other classes, test on it.
- ``views``: new views of seen objects; a seeded 20% of the (instance, view)
  groups is held out per run. Occluded copies of a view share its group, and so
  do frames of an instance with the same pose (a grid that repeats a view), so a
  view is never on both sides of a split (view_groups).
- ``instances``: category-level pose; fold f tests the f-th instance of every
  class (in a seeded order per run) and trains on the others, so every frame
  is tested once per run and no instance is on both sides of a split.
- ``offgrid`` (our reading of the paper's Fig. 5): train on every frame of one
  folder (a camera grid), test on every frame of another (views at random
  poses, occluded by rectangles or 3-D distractors); test frames whose
  instance is in the training folder are "seen", the others "unseen".
- ``interleaved``: train on every other view of each camera path (even path
  index), test on the views between (odd): on a turntable in 5-degree steps,
  train on the 10-degree views and test on the 5-degree views between them.
  Occluded copies of a view share its path index, so they fall on its side.

Every method stands alone: before ``fit`` the benchmark checks what the method declares it
needs (``NEEDS``: depth, SPM features, camera paths, frames; spm_model/base/estimator.py), and
a method whose needs the training frames do not meet, or whose ``fit`` or ``predict`` raises,
is *declined* in that split with its one-line reason; the others run and are scored. The
test frames of a split a method declined count as frames without its estimate.

Methods get training frames (spm_model/base/frames.py) with their poses, then test frames that
hold only what a camera sees (image, visible mask, K), in a seeded random order, and return (n, 6)
labels; a NaN row is a frame without an estimate and counts as a failure. ``train_occluded`` (the
paper's Appendix, training with noise): whether frames with occlusion train too; by default they
do under loco, views and instances (as before) and do not under offgrid. Runs differ in their
seed: the model's random choices, the views split, the instances order and the test order (the
features are extracted once, with a fixed seed, and cached). Under loco and offgrid the splits
are the same in every run (and under interleaved), so a DETERMINISTIC method (no seed: pca, ls,
n3m, sift-pnp, template; spm_model/base/estimator.py) is fitted in the first run only and its
predictions are reused in the others: the same scores as fitting it again.
"""

from __future__ import annotations

import numpy as np

from spm_model.errors import ModelError
from spm_model.base.feature_memo import use_folder
from spm_model.bench.final_models import fit_final_models, saved_names
from spm_model.bench.fitting import builtin_classes, fit_predict
from spm_model.bench.isolation import DEFAULT_TIMEOUT
from spm_model.bench.jobs import FinalJob, SplitJob
from spm_model.bench.feature_cache import FeatureTable, load_features, memo_folder, offgrid_table, progress_phase
from spm_model.bench.scoring import eccentricity, frame_errors, run_summary
from spm_model.bench.split_lines import SplitLines
from spm_model.bench.surface_metrics import mesh_keys
from spm_model.bench.symmetry_errors import instance_symmetries

PROTOCOLS = ("loco", "views", "instances", "offgrid", "interleaved")


def _instances_splits(table: FeatureTable, seed: int):
    rng = np.random.default_rng(seed)
    order = {}
    for c in sorted(set(table.class_name.tolist())):
        names = sorted(set(table.instance[table.class_name == c].tolist()))
        if len(names) < 2:
            raise ModelError(f"the instances protocol needs at least 2 instances of every class; {c!r} has "
                             f"{len(names)}; render more instances or use --protocol views")
        order[c] = [names[i] for i in rng.permutation(len(names))]
    out = []
    for fold in range(max(len(v) for v in order.values())):
        held = [names[fold] for names in order.values() if fold < len(names)]
        test = np.isin(table.instance, held)
        out.append((f"fold {fold + 1}", np.flatnonzero(~test), np.flatnonzero(test)))
    return out


def view_groups(table: FeatureTable) -> np.ndarray:
    """(n,) str: the view of each frame, "instance#path_index", where frames of an instance with
    the same pose (rotation and translation to 1e-6) share the smallest path index among them:
    occluded copies of a view, and a grid that repeats a view (azimuth 0 and 360), are one view."""
    from spm_data.core.poses import label_to_pose

    R, t = label_to_pose(np.asarray(table.pose, dtype=np.float64))
    pose = np.round(np.concatenate([R.reshape(len(R), 9), t], axis=1), 6) + 0.0   # + 0.0: no -0.0
    keys = np.char.add(np.char.add(table.instance.astype(str), "#"), [",".join(map(repr, p)) for p in pose.tolist()])
    _, same_pose = np.unique(keys, return_inverse=True)
    first = np.full(same_pose.max() + 1 if len(keys) else 0, np.iinfo(np.int64).max)
    np.minimum.at(first, same_pose, np.asarray(table.path_index, dtype=np.int64))
    return np.char.add(np.char.add(table.instance.astype(str), "#"), first[same_pose].astype(str))


def splits(table: FeatureTable, protocol: str, seed: int, held_out: float = 0.2):
    """[(what is tested, train index, test index)]: per class for loco, per fold
    for instances, one split for views and offgrid (offgrid: the table's ``test`` column)."""
    classes = sorted(set(table.class_name.tolist()))
    if protocol == "loco":
        if len(classes) < 2:
            raise ModelError(f"leave-one-class-out needs at least 2 classes, found {classes}; "
                             "add shards of other classes or use --protocol views")
        return [(c, np.flatnonzero(table.class_name != c), np.flatnonzero(table.class_name == c)) for c in classes]
    if protocol == "views":
        unique, inverse = np.unique(view_groups(table), return_inverse=True)
        test_groups = np.random.default_rng(seed).random(len(unique)) < held_out
        test = test_groups[inverse]
        return [("all", np.flatnonzero(~test), np.flatnonzero(test))]
    if protocol == "instances":
        return _instances_splits(table, seed)
    if protocol == "interleaved":
        even = np.asarray(table.path_index, dtype=np.int64) % 2 == 0
        return [("every other view", np.flatnonzero(even), np.flatnonzero(~even))]
    if protocol == "offgrid":
        if "test" not in table.arrays:
            raise ModelError("the offgrid protocol needs a test folder: give --test FOLDER (views rendered at "
                             "random poses, occluded; see README, Fig. 5)")
        return [("test folder", np.flatnonzero(~table.test), np.flatnonzero(table.test))]
    raise ModelError(f"protocol must be one of {PROTOCOLS}, got {protocol!r}")


def training_rows(table: FeatureTable, train: np.ndarray, train_occluded: bool) -> np.ndarray:
    """``train`` without its occluded frames unless ``train_occluded``."""
    return train if train_occluded else train[table.occlusion_fraction[train] <= 0]


_TABLES: dict = {}  # per process: the feature tables split jobs read, by source
_MEMO: list = [None]  # per process: the feature memo folder of the table in _TABLES (for the methods' processes)
_MESHES: dict = {}  # per process: (mesh keys, symmetries) of the table in _TABLES, by source


def _table(source) -> FeatureTable:
    """The feature table of ``source`` (shards, test folder or None, FeatureConfig, allow_partial),
    loaded once per process from the feature cache."""
    if source not in _TABLES:
        shards, test, config, allow_partial = source
        table = load_features(shards, config, allow_partial=allow_partial)
        if test is not None:
            table = offgrid_table(table, load_features(test, config, allow_partial=allow_partial))
        _TABLES.clear()  # one table per process at a time
        _MESHES.clear()
        _TABLES[source] = table
        _MEMO[0] = memo_folder(table.shard[0], config) if len(table) else None
        if len(table):  # N3M's and SMM's local features, shared by workers, runs and protocols
            use_folder(_MEMO[0])
    return _TABLES[source]


def _meshes(source) -> tuple:
    """(mesh keys, declared symmetries) per frame of ``source``'s table, once per process."""
    if source not in _MESHES:
        table = _table(source)
        keys = mesh_keys(table.shard, table.instance_id)
        _MESHES.clear()
        _MESHES[source] = keys, instance_symmetries(keys)
    return _MESHES[source]


def split_job(job, report=lambda n: None):
    """One (run, split) on any worker: every method fitted and asked in a fresh process of its own
    (fitting.fit_predict), which gets the training frames and poses and the test frames only; the
    labels stay here. job: a SplitJob (spm_model/bench/jobs.py). Returns (what
    was tested, training frames, test index, {method: per-frame errors}, notes): the errors
    (scoring.frame_errors) are scored here, so the splits' scoring runs on the workers too, and only
    the errors travel back; a declined method's errors are those of no estimate. notes =
    {"declined": {method: why}, "featured": {method: test frames with its features, or None}}."""
    source, protocol, run, index = job.source, job.protocol, job.run, job.index
    model_params, builtins, estimators, timeout = job.model_params, job.builtins, job.estimators, job.timeout
    train_occluded = job.train_occluded
    table = _table(source)
    tested, train, test = splits(table, protocol, seed=run)[index]
    train = training_rows(table, train, train_occluded)
    if len(train) == 0:
        raise ModelError(f"{protocol} protocol, run {run + 1}: nothing left to train on when testing {tested}")
    if len(test) == 0:
        return tested, 0, test, {}, {"declined": {}, "featured": {}}
    methods = list(builtin_classes(model_params, builtins)) + list(estimators or {})
    if not methods:   # a later run whose methods are all reused from the first (evaluate)
        report(len(test))
        return tested, len(train), test, {}, {"declined": {}, "featured": {}}
    predictions, declined, featured = fit_predict((run, model_params, builtins, estimators), table, train, test,
                                                  seed=run, timeout=timeout, tick=lambda: report(0), memo=_MEMO[0])
    keys, symmetries = _meshes(source)
    none = np.full((len(test), 6), np.nan)
    errors = {name: frame_errors(table, test, predictions.get(name, none), keys, symmetries) for name in methods}
    report(len(test))
    # Of the scored frames (a measured angle), as `frames` and `estimated` count them.
    counts = {name: None if featured.get(name) is None else
              int(featured[name][~np.isnan(errors[name]["rotation_max"])].sum()) for name in methods}
    return tested, len(train), test, errors, {"declined": declined, "featured": counts}


def evaluate(table: FeatureTable, protocol: str = "loco", runs: int = 3, model_params: dict | None = None,
             estimators: dict | None = None, report=lambda message: None, builtins=None,
             train_occluded: bool | None = None, executor=None, source=None, final: bool = False,
             progress=None, timeout: float | None = DEFAULT_TIMEOUT) -> dict:
    """Every run x split for the built-in methods (``builtins``: their names, default all) and
    ``estimators`` ({name: class}, instantiated fresh per split): per-class and overall summaries
    per method, the geodesic accuracy curve and the occlusion bins (offgrid: also per seen/unseen
    instance and occluder, "fig5"). train_occluded: None for the protocol's default (module docstring).
    executor, source: the splits of every run as jobs on ``executor`` (spm_data.jobs), each worker
    reading the table from the feature cache of ``source`` = (shards, test folder or None,
    FeatureConfig, allow_partial); the results are those of one worker. Without them, in this process.
    final: also fit the final models (final_models.fit_final_models), one job per model after the
    splits: a worker that has no split left fits one while the others finish theirs (handed out
    first, the worker that fitted them ended its last split after the others had none left:
    docs/scaling.md).
    timeout: seconds a plug-in's call may take before it is declined (None: no limit). progress: a
    callable taking count deltas (feature_cache.progress_phase): "fitting" counts the splits (not
    the final models), "scoring" runs.
    Returns {"protocol", "runs": [...], "eccentricity", "classes", "methods", "train_occluded"} (and
    with ``final`` "final_models": fit_final_models' (fitted, declined) of every model, in report order)."""
    if protocol not in PROTOCOLS:
        raise ModelError(f"protocol must be one of {PROTOCOLS}, got {protocol!r}")
    train_occluded = (protocol != "offgrid") if train_occluded is None else bool(train_occluded)
    key = source if source is not None else ("in-process", id(table))
    _TABLES.clear()
    _MESHES.clear()
    _TABLES[key] = table
    _MEMO[0] = memo_folder(table.shard[0], source[2]) if source is not None and len(table) else None
    reused = _reused_methods(protocol, runs, model_params, builtins, estimators)
    later = _without(builtins, estimators, model_params, reused)   # the methods of runs after the first
    jobs = [SplitJob(key, protocol, run, i, dict(model_params or {}), *(later if run else (builtins, estimators)),
                     train_occluded, timeout)
            for run in range(runs) for i in range(len(splits(table, protocol, seed=run)))]
    wanted = saved_names(builtins)   # only what was asked for
    # One job per saved model, so that two workers fit two at once; handed out longest first (reverse
    # report order: the registry keeps cnn, the slowest, the last row with a model file).
    finals = [FinalJob(key, dict(model_params or {}), train_occluded, (name,)) for name in wanted[::-1]
              if final]
    progress = progress or (lambda n: None)
    progress_phase(progress, "fitting", len(jobs), "split")
    outputs = _run_jobs(jobs + finals, executor if source is not None else None, report, progress)
    models, outputs = (_merged(outputs[len(jobs):], wanted), outputs[:len(jobs)]) if final else (None, outputs)
    if reused:
        first = {job.index: outputs[i] for i, job in enumerate(jobs) if job.run == 0}
        outputs = [_with_first_run(out, first[job.index]) if job.run else out for job, out in zip(jobs, outputs)]
    results = []
    progress_phase(progress, "scoring", runs, "run")
    for run in range(runs):
        parts = [outputs[i] for i, job in enumerate(jobs) if job.run == run and len(outputs[i][2])]
        if not parts:
            raise ModelError(f"{protocol} protocol, run {run + 1}: no frame was held out for testing "
                             f"({len(table)} frames); add views or instances, or use another protocol")
        results.append(run_summary(table, protocol, run, parts))
        progress(1)
    return {"protocol": protocol, "runs": results, "eccentricity": eccentricity(table),
            "classes": sorted(set(table.class_name.tolist())), "methods": list(results[0]["overall"]),
            "train_occluded": train_occluded, **({"final_models": models} if final else {})}


def _merged(final_outputs: list, order) -> tuple[dict, dict]:
    """The (fitted, declined) pairs of the final-model jobs (fit_final_models) as one pair, the
    models in ``order`` (report order)."""
    fitted, declined = {}, {}
    for models, why in final_outputs:
        fitted.update(models)
        declined.update(why)
    return {name: fitted[name] for name in order if name in fitted}, declined


# Protocols whose splits are the same in every run (they ignore the run's seed).
SAME_SPLITS_EVERY_RUN = ("loco", "offgrid", "interleaved")


def _reused_methods(protocol: str, runs: int, model_params, builtins, estimators) -> set:
    """Names of the methods fitted in the first run only and reused in the others (the same scores):
    the DETERMINISTIC ones (spm_model/base/estimator.py) under a protocol whose splits are the same."""
    if protocol not in SAME_SPLITS_EVERY_RUN or runs < 2:
        return set()
    classes = {**builtin_classes(model_params, builtins), **(estimators or {})}  # plug-ins: never built here
    return {name for name, cls in classes.items() if getattr(cls, "DETERMINISTIC", False) is True}


def _without(builtins, estimators, model_params, reused: set) -> tuple:
    """(builtins, estimators) but the reused methods (builtins None: every built-in one)."""
    if not reused:
        return builtins, estimators
    return ([name for name in builtin_classes(model_params, builtins) if name not in reused],
            {name: cls for name, cls in (estimators or {}).items() if name not in reused})


def _with_first_run(output: tuple, first: tuple) -> tuple:
    """A later run's split_job output with the reused methods' errors taken from the first
    run's output of the same split, in the first run's method order."""
    tested, n_train, test, errors, notes = output
    if not np.array_equal(test, first[2]):
        raise ModelError(f"internal: split {tested!r} differs between runs; cannot reuse its predictions")
    order = list(first[3]) + [name for name in errors if name not in first[3]]
    errors = {**first[3], **errors}
    # Only the reused methods' notes come from the first run (one declined there may run here).
    notes = {k: {**{n: v for n, v in first[4][k].items() if n not in notes["featured"]}, **notes[k]}
             for k in ("declined", "featured")}
    return tested, n_train, test, {n: errors[n] for n in order}, notes


def final_rows(table: FeatureTable, train_occluded: bool) -> np.ndarray:
    """The rows spm train's saved models are fitted on: every training frame (offgrid: every frame of
    the training folder), without occluded ones unless ``train_occluded``."""
    rows = np.flatnonzero(~table.test) if "test" in table.arrays else np.arange(len(table))
    return training_rows(table, rows, train_occluded)


def bench_job(job, report=lambda n: None):
    """A SplitJob (split_job), or a FinalJob: its final models (fit_final_models) on the table's final_rows.
    Runs on one BLAS thread wherever it runs: LAPACK's threaded solvers round differently
    with 2 threads than with 1, and SPM's RBF system amplifies that (0.003 degrees), so the
    BLAS threads of a worker (cores / --workers) would otherwise change results.json and
    model.npz. The workers, not BLAS, are the benchmark's parallelism."""
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1, user_api="blas"):
        if isinstance(job, FinalJob):
            try:
                table = _table(job.source)
                return fit_final_models(table, job.model_params, final_rows(table, job.train_occluded), job.wanted)
            except ModelError as exc:
                raise ModelError(f"final {', '.join(job.wanted)} model (on every training frame): {exc}") from None
        return split_job(job, report)


def _run_jobs(jobs: list, executor, report, progress) -> list:
    """Outputs of bench_job for every job, in order, ``progress(1)`` as each split job ends (the
    final models are not a split: counted, a quick one would make the time left a guess from it),
    each split's line said in job order (split_lines.py); in this process without an executor."""
    lines = SplitLines(jobs, report)

    def said(job, output):
        if isinstance(job, SplitJob):
            progress(1)
        lines(job, output)

    if executor is None:
        outputs = []
        for job in jobs:
            outputs.append(bench_job(job))
            said(job, outputs[-1])
        return outputs
    outcomes = executor.run(bench_job, jobs, on_outcome=lambda o: said(o.job, None if o.error else o.result))
    failed = [o for o in outcomes if o.error]
    if failed:
        raise ModelError(failed[0].error if failed[0].error.count("\n") == 0 else failed[0].error.splitlines()[-1])
    return [o.result for o in outcomes]

"""Every method fitted and asked on its own (spm_model/bench/protocols.py runs the splits), in a
fresh process per split (spm_model/bench/isolation.py) that never holds a test label: what a
method declares it needs (``NEEDS``, spm_model/base/estimator.py) checked against the training
frames before ``fit``; a method whose needs are not met, or whose ``fit`` or ``predict`` raises,
exits, runs past the time limit or returns the wrong thing, is *declined* with a one-line reason
and the others go on; the test frames each method found its features on (``features_found``)."""

from __future__ import annotations

import numpy as np

from spm_data.errors import SpmError, one_line
from spm_model.errors import ModelError
from spm_model.base.estimator import needs_of
from spm_model.base.frames import Frames, camera_chunks, camera_paths, read_camera_frames
from spm_model.bench.feature_cache import FeatureTable
from spm_model.bench.isolation import DEFAULT_TIMEOUT, Lost, fresh_process
from spm_model.methods.registry import builtin_methods


def unmet_needs(method, table: FeatureTable, train: np.ndarray) -> str | None:
    """Why ``method`` (an instance or class) cannot fit on the rows ``train`` of ``table``, by
    what it declares it needs (``NEEDS``, spm_model/base/estimator.py); None when it can."""
    needs = needs_of(method)   # a class, an instance or a PluginRef (plugin_refs.py)
    if len(train) < needs.frames:
        return f"needs {needs.frames} training frames or more, got {len(train)}"
    if needs.depth and "has_depth" in table.arrays and not table.has_depth[train].any():
        return (f"needs depth: none of the {len(train)} training frames has a measured depth (imported photos "
                "such as COIL have none; renders, BOP and captures with depth images do)")
    if needs.spm_features:
        usable = int(np.isfinite(table.train_vector[train]).all(axis=1).sum())
        if usable < needs.spm_features:
            return (f"needs {needs.spm_features} training frames with SPM features, {usable} of {len(train)} have "
                    "them (SIFT finds too few keypoints on small or plain images)")
    if needs.sequences > 1:
        paths = len(np.unique(camera_paths(table, train)))
        if paths < needs.sequences:
            return f"needs {needs.sequences} camera paths (sequences) among the training frames, got {paths}"
    return None


def failure(exc: BaseException, stage: str = "") -> str:
    """One line for a method that raised: its message (an SpmError says why it cannot run on this
    data), or the exception's type and message for anything else (a bug, reported, not fatal)."""
    text = one_line(exc) if isinstance(exc, SpmError) else f"{type(exc).__name__}: {one_line(exc)}"
    return f"{stage}{text}"[:500]


def call_failure(exc: BaseException, stage: str = "") -> str:
    """failure(), with what SystemExit and KeyboardInterrupt raised by a method mean: it tried to
    end the run (its exit code) or raised the interruption itself (never the user's Ctrl-C)."""
    if isinstance(exc, SystemExit):
        return f"{stage}it raised SystemExit (exit code {exc.code!r}); a method cannot end the run"[:500]
    if isinstance(exc, KeyboardInterrupt):
        return f"{stage}it raised KeyboardInterrupt itself (not the user's Ctrl-C)"
    return failure(exc, stage)


class Unbuilt:
    """Stands in for a plug-in whose constructor raised: it declines in every split, with why."""

    def __init__(self, why: str):
        self.why = why

    def fit(self, frames, poses):
        raise ModelError(self.why)


def construct(cls):
    """``cls()``, or an :class:`Unbuilt` saying why it could not be made."""
    try:
        return cls()
    except Exception as exc:  # noqa: BLE001 - a plug-in can fail in any way; it is declined, not fatal
        return Unbuilt(failure(exc, f"{getattr(cls, '__name__', cls)}(): "))


def found_flags(model, frames) -> np.ndarray | None:
    """(len(frames),) bool: the frames the fitted ``model`` found its features on (its optional
    ``features_found``), or None when it does not say (or fails to)."""
    found = getattr(model, "features_found", None)
    if not callable(found):
        return None
    try:
        flags = np.asarray(found(frames), dtype=bool)
    except Exception:  # noqa: BLE001 - a count for the report; the method's estimates stand
        return None
    return flags if flags.shape == (len(frames),) else None


def make_methods(seed: int, model_params: dict, builtins=None, estimators=None) -> dict:
    """Fresh built-in methods (``builtins``: their names, default all) and plug-ins ({name: class})."""
    params = dict(model_params)
    features = params.pop("features")
    methods = {k: v for k, v in builtin_methods(seed, features, params).items() if builtins is None or k in builtins}
    methods.update({name: construct(cls) for name, cls in (estimators or {}).items()})
    return methods


def builtin_classes(model_params, builtins=None) -> dict:
    """{name: class} of the built-in methods ``builtins`` names (None: all), in report order."""
    params = dict(model_params or {})
    return {name: type(method) for name, method in builtin_methods(0, params.pop("features"), params).items()
            if builtins is None or name in builtins}


def fit_predict(recipe: tuple, table: FeatureTable, train: np.ndarray, test: np.ndarray, seed: int = 0, *,
                timeout: float | None = DEFAULT_TIMEOUT, tick=None, memo=None):
    """The methods of ``recipe`` = (seed, model_params, built-in names or None for all, {plug-in name:
    class or plugin_refs.PluginRef}) fitted on ``train`` and asked for ``test``, in a fresh process of their own
    (spm_model/bench/isolation.py): ({name: (len(test), 6) predictions, in ``test``'s order}, {name:
    why it declined}, {name: (len(test),) bool, the test frames it found features on, or None}). A
    method declined (unmet needs; fit or predict raising, exiting, or a plug-in's call past
    ``timeout`` seconds; output of the wrong shape) has no predictions; the others are unaffected.
    Methods see the test frames as a camera gives them (CameraFrames), in a random order seeded by
    ``seed``, a bounded chunk of images at a time. tick: called about once a second while waiting.
    memo: the feature memo folder the child uses (spm_model/base/feature_memo.py)."""
    run, params, builtins, plugins = recipe
    plugins = dict(plugins or {})
    classes = {**builtin_classes(params, builtins), **plugins}
    declined = {name: why for name, cls in classes.items() if (why := unmet_needs(cls, table, train)) is not None}
    names = [name for name in classes if name not in declined]
    order = np.random.default_rng(seed).permutation(len(test))
    chunks = camera_chunks(table, test[order])
    held = [read_camera_frames(table, chunks[0])] if len(chunks) == 1 else None   # read once, sent per child
    parts: dict = {}
    while names:
        child = fresh_process()
        try:
            parts = _ask(child, (run, params, plugins), names, Frames(table, train), table.pose[train].copy(),
                         held or (read_camera_frames(table, c) for c in chunks), timeout, tick, memo, declined)
            break
        except Lost as lost:   # its process ended: the methods left start again in a new one
            declined[lost.name] = lost.why
            names.remove(lost.name)
        finally:
            child.close()
    out, flags = {}, {}
    for name, (preds, found) in parts.items():
        out[name] = np.full((len(test), 6), np.nan)
        out[name][order] = np.concatenate(preds) if preds else np.zeros((0, 6))
        if found is not None:
            flags[name] = np.zeros(len(test), bool)
            flags[name][order] = np.concatenate(found) if found else np.zeros(0, bool)
    return out, declined, {name: flags.get(name) for name in out}


def _ask(child, recipe, names, frames, poses, chunks, timeout, tick, memo, declined) -> dict:
    """{name: ([predictions per chunk], [flags per chunk] or None)} of the methods the child fitted;
    those it declined go in ``declined``. Lost when the child ends or a plug-in's call runs too long."""
    plugins = recipe[2]
    limit = {name: timeout if name in plugins else None for name in names}
    child.send(("start", recipe, names, frames, poses, memo))
    parts = {}
    for name in names:
        header, _ = child.reply(name, "fit: ", limit[name], tick)
        if header["why"] is None:
            parts[name] = ([], [])
        else:
            declined[name] = header["why"]
    for chunk in chunks:
        child.send(chunk)
        for name in list(parts):
            header, arrays = child.reply(name, "predict: ", limit[name], tick)
            if header["why"] is not None:
                declined[name] = header["why"]
                del parts[name]
                continue
            if not arrays or arrays[0].shape != (len(chunk), 6) or arrays[0].dtype != np.float64:
                raise Lost(name, "predict: the method's process sent something that is not its predictions")
            parts[name][0].append(arrays[0])
            found = parts[name][1]
            ok = len(arrays) == 2 and arrays[1].shape == (len(chunk),) and arrays[1].dtype == bool
            parts[name] = (parts[name][0], found + [arrays[1]] if found is not None and ok else None)
    return parts

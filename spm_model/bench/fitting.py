"""Every method fitted and asked on its own (spm_model/bench/protocols.py runs the splits): what
a method declares it needs (``NEEDS``, spm_model/base/estimator.py) checked against the training
frames before ``fit``; a method whose needs are not met, or whose ``fit`` or ``predict`` raises
or returns the wrong thing, is *declined* with a one-line reason and the others go on; the test
frames each method found its features on (its optional ``features_found``)."""

from __future__ import annotations

import numpy as np

from spm_data.errors import ModelError, SpmError, one_line
from spm_model.base.estimator import needs_of
from spm_model.base.frames import Frames, camera_chunks, camera_paths, read_camera_frames
from spm_model.bench.feature_cache import FeatureTable
from spm_model.methods.registry import check_predictions


def unmet_needs(method, table: FeatureTable, train: np.ndarray) -> str | None:
    """Why ``method`` (an instance or class) cannot fit on the rows ``train`` of ``table``, by
    what it declares it needs (``NEEDS``, spm_model/base/estimator.py); None when it can."""
    needs = needs_of(method if isinstance(method, type) else type(method))
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


def failure(exc: Exception, stage: str = "") -> str:
    """One line for a method that raised: its message (an SpmError says why it cannot run on this
    data), or the exception's type and message for anything else (a bug, reported, not fatal)."""
    text = one_line(exc) if isinstance(exc, SpmError) else f"{type(exc).__name__}: {one_line(exc)}"
    return f"{stage}{text}"[:500]


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


def _found(model, frames) -> np.ndarray | None:
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


def _fit(method, table: FeatureTable, train: np.ndarray):
    """(the fitted method, None) or (None, why it declined)."""
    why = unmet_needs(method, table, train)
    if why is not None:
        return None, why
    try:
        model = method.fit(Frames(table, train), table.pose[train].copy())
    except Exception as exc:  # noqa: BLE001 - one method's failure never takes the others down
        return None, failure(exc)
    if model is None:
        return None, "fit(frames, poses) returned None; it must return self"
    return model, None


def fit_predict(methods: dict, table: FeatureTable, train: np.ndarray, test: np.ndarray, seed: int = 0):
    """Every method fitted on ``train``, then asked for the test frames: ({name: (len(test), 6)
    predictions, in ``test``'s order}, {name: why it declined}, {name: (len(test),) bool, the
    test frames it found features on, or None}). A method declined (unmet needs, fit or predict
    raising, output of the wrong shape) has no predictions; the others are unaffected. Methods see the test frames
    as a camera gives them (CameraFrames), in a random order seeded by ``seed``, a bounded chunk
    of images at a time."""
    fitted, declined = {}, {}
    for name, method in methods.items():
        model, why = _fit(method, table, train)
        if why is None:
            fitted[name] = model
        else:
            declined[name] = why
    order = np.random.default_rng(seed).permutation(len(test))
    parts = {name: [] for name in fitted}
    found = {name: [] for name in fitted}
    for chunk in camera_chunks(table, test[order]):
        frames = read_camera_frames(table, chunk)
        for name, model in list(fitted.items()):
            try:
                parts[name].append(check_predictions(name, model.predict(frames), len(chunk)))
            except Exception as exc:  # noqa: BLE001 - as in fit
                declined[name] = failure(exc, "predict: ")
                del fitted[name]
                continue
            flags = _found(model, frames)
            found[name] = None if flags is None or found[name] is None else found[name] + [flags]
    out, flags = {}, {}
    for name in fitted:
        pred = np.full((len(test), 6), np.nan)
        pred[order] = np.concatenate(parts[name]) if parts[name] else np.zeros((0, 6))
        out[name] = pred
        if found[name] is not None:
            flags[name] = np.zeros(len(test), bool)
            flags[name][order] = np.concatenate(found[name]) if found[name] else np.zeros(0, bool)
    return out, declined, {name: flags.get(name) for name in fitted}

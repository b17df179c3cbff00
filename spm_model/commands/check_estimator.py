"""The library call behind ``spm check-estimator MODULE:CLASS``: a plug-in run through the estimator
contract (spm_model/base/estimator.py) on a small built-in set, as scikit-learn's
``check_estimator`` does, one line a check.

The set: two procedural classes (box, cup), two instances each, 24 views of each instance at
64 x 64 px, rendered with pyrender into a temporary folder and read back as the benchmark reads
any folder (features cached, frames served as spm_model/base/frames.py serves them). The
training frames are the even views of each camera path, the test frames the odd ones (the
``interleaved`` protocol), handed over as a camera gives them. Checks marked FAIL break what
the benchmark relies on; notes describe the estimator without failing it.
"""

from __future__ import annotations

import pickle
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from spm_data.errors import SpmError, one_line

CHECK_SPEC = """
class = "{cls}"
seed = 11
[mesh]
instances = 2
[camera]
azimuth = [0, 55, 5]
elevation = [10, 15, 5]
distances = [0.6]
[image]
width = 64
height = 64
[render]
renderer = "pyrender"
frames_per_shard = 48
"""
CLASSES = ("box", "cup")


@dataclass(frozen=True)
class Check:
    """One check's outcome: ``status`` "ok", "FAIL" or "note"; ``text`` says what was checked
    and, where it failed, what happened and the fix."""

    status: str
    text: str

    def line(self) -> str:
        return f"{self.status:<5} {self.text}"


def built_in_set(folder: Path, progress=None):
    """Render the check's set into ``folder`` and return its feature table (FeatureTable)."""
    from spm_data.commands.render_jobs import render_dataset
    from spm_data.core.specs import parse_spec
    from spm_model.bench.feature_cache import load_features, progress_phase
    from spm_model.spm.features import FeatureConfig

    specs = [parse_spec(CHECK_SPEC.format(cls=c), name=f"check-{c}") for c in CLASSES]
    progress_phase(progress, "rendering the check set")
    try:
        render_dataset(specs, folder, progress=progress)
    except SpmError as exc:
        raise SpmError(f"cannot render the built-in set with pyrender: {one_line(exc)}") from None
    return load_features(folder, FeatureConfig(), progress=progress)


def _call(fn, *args):
    """(value, None) or (None, why): our errors' message, anything else's type and message."""
    from spm_model.bench.fitting import failure

    try:
        return fn(*args), None
    except Exception as exc:  # noqa: BLE001 - a plug-in can fail in any way; each check reports it
        return None, failure(exc)[:300]


class _Checks:
    """The checks in order; each appends to ``self.done`` and says whether later ones can run."""

    def __init__(self, cls, table):
        from spm_model.base.frames import Frames, read_camera_frames

        self.cls, self.table, self.done = cls, table, []
        even = np.asarray(table.path_index) % 2 == 0
        self.train, self.test = np.flatnonzero(even), np.flatnonzero(~even)
        self.frames = Frames(table, self.train)
        self.poses = table.pose[self.train].copy()
        self.camera = read_camera_frames(table, self.test)
        self.deterministic = getattr(cls, "DETERMINISTIC", False) is True

    def add(self, ok, text: str, fix: str = "", note: bool = False) -> bool:
        status = "ok" if ok else ("note" if note else "FAIL")
        self.done.append(Check(status, text if ok or not fix else f"{text}: {fix}"))
        return bool(ok)

    def construct(self):
        model, error = _call(self.cls)
        self.add(error is None, "constructs with no arguments", f"{error}; give every parameter a default")
        return model

    def needs(self) -> None:
        from spm_model.base.estimator import needs_of

        needs, error = _call(needs_of, self.cls)
        self.add(error is None, f"declares what it needs ({needs})" if error is None else "declares what it needs",
                 error or "")

    def params(self, model) -> None:
        if not callable(getattr(model, "get_params", None)):
            self.add(False, "get_params(): not defined (optional; the report records no parameters)", note=True)
            return
        params, error = _call(model.get_params)
        if error is None and isinstance(params, dict):
            again, error = _call(lambda: self.cls(**params).get_params())
            same = error is None and repr(again) == repr(params)
            self.add(same, "__init__ stores its parameters as given (get_params round trip)",
                     error or f"cls(**get_params()) gave {again!r}, not {params!r}; store each keyword as it is")
        else:
            self.add(False, "get_params() returns a dict", error or f"got {type(params).__name__}")

    def unfitted(self) -> None:
        model, error = _call(self.cls)
        out, error = _call(model.predict, self.camera) if model is not None else (None, error)
        self.add(error is not None, "predict before fit raises",
                 "it returned a result; raise an error until fit has run (spm_model.base.estimator.check_fitted)")

    def fit(self, model):
        poses = self.poses.copy()
        fitted, error = _call(model.fit, self.frames, poses)
        if error is not None:
            self.add(False, f"fit(frames, poses) on {len(self.train)} frames", error)
            return None
        self.add(np.array_equal(poses, self.poses), "fit leaves the poses it was given unchanged",
                 "it modified its poses argument; copy before changing")
        ok = self.add(fitted is model, "fit returns self",
                      f"it returned {type(fitted).__name__}; end fit with `return self`")
        return model if ok else None

    def predict(self, model):
        from spm_model.methods.registry import check_predictions

        raw, error = _call(model.predict, self.camera)
        if error is None:
            out, error = _call(check_predictions, self.cls.__name__, raw, len(self.test))
        if not self.add(error is None, f"predict(frames) returns ({len(self.test)}, 6) labels", error or ""):
            return None
        partial = int((np.isnan(out).any(axis=1) & ~np.isnan(out).all(axis=1)).sum())
        self.add(partial == 0, "rows are whole estimates or all NaN",
                 f"{partial} rows are part NaN; they count as no estimate where the data measures that part",
                 note=True)
        return out

    def repeat(self, model, out) -> None:
        again, error = _call(model.predict, self.camera)
        same = error is None and np.array_equal(np.asarray(again, dtype=np.float64), out, equal_nan=True)
        self.add(same, "predict repeats (the same frames, the same labels)",
                 error or "a second call gave other labels" + ("; DETERMINISTIC promises it" if self.deterministic
                                                                else ""), note=not self.deterministic)
        one, error = _call(model.predict, self.camera[[0]])
        same = error is None and np.array_equal(np.asarray(one, dtype=np.float64).reshape(-1), out[0],
                                                equal_nan=True)
        self.add(same, "a frame's label does not depend on the frames predicted with it",
                 error or "predicting frame 0 alone gave another label" + (
                     "; DETERMINISTIC promises it" if self.deterministic else ""), note=not self.deterministic)
        empty, error = _call(model.predict, self.camera[[]])
        ok = error is None and np.shape(np.asarray(empty, dtype=np.float64)) == (0, 6)
        self.add(ok, "predict of no frames returns (0, 6)", error or f"got shape {np.shape(empty)}", note=True)

    def found(self, model) -> None:
        fn = getattr(model, "features_found", None)
        if not callable(fn):
            self.add(False, "features_found(frames): not defined (optional; reports show – for its feature "
                            "count)", note=True)
            return
        flags, error = _call(fn, self.camera)
        ok = error is None and np.shape(flags) == (len(self.test),)
        self.add(ok, "features_found(frames) returns one flag per frame",
                 error or f"got shape {np.shape(flags)}, expected ({len(self.test)},)")

    def workers(self) -> None:
        import importlib

        module, error = _call(importlib.import_module, self.cls.__module__)
        same = error is None and getattr(module, self.cls.__qualname__, None) is self.cls
        _, pickled = _call(pickle.dumps, self.cls)
        self.add(same and pickled is None, "importable by its module path, for worker processes (--workers)",
                 error or pickled or f"{self.cls.__module__}.{self.cls.__qualname__} is not that class")

    def score(self, out) -> None:
        from spm_model.bench.metrics import pose_errors, tolerance_rate

        errors = pose_errors(out, self.table.pose[self.test], self.table.label_measured[self.test])
        rate = tolerance_rate(errors["rotation_max"])
        estimated = int(np.isfinite(errors["rotation_max"]).sum())
        self.add(False, f"on this set: {estimated} of {len(self.test)} test frames estimated, "
                        f"{rate:.1f}% within ±5° (the views between the training views, 5° from one)", note=True)


def check_estimator(spec: str, *, progress=None, log=lambda line: None) -> list[Check]:
    """Run the plug-in ``spec`` ('MODULE:CLASS') through the contract; every Check, each also
    passed to ``log`` (one line) as it is made. ModelError (one line) when it cannot be loaded."""
    from spm_model.bench.feature_cache import progress_phase
    from spm_model.methods.registry import load_estimator_class

    cls = load_estimator_class(spec)
    folder = Path(tempfile.mkdtemp(prefix="spm-check-estimator-"))
    try:
        checks = _Checks(cls, built_in_set(folder / "set", progress))
        progress_phase(progress, "checks", None, None)
        _run(checks, log)
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    return checks.done


def _run(checks: _Checks, log) -> None:
    def step(fn, *args):
        before = len(checks.done)
        value = fn(*args)
        for check in checks.done[before:]:
            log(check.line())
        return value

    step(checks.workers)
    step(checks.needs)
    model = step(checks.construct)
    if model is None:
        return
    step(checks.params, model)
    step(checks.unfitted)
    model = step(checks.fit, model)
    if model is None:
        return
    out = step(checks.predict, model)
    if out is None:
        return
    step(checks.repeat, model, out)
    step(checks.found, model)
    step(checks.score, out)


def failed(checks: list[Check]) -> list[Check]:
    return [c for c in checks if c.status == "FAIL"]


__all__ = ["Check", "check_estimator", "failed"]

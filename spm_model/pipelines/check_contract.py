"""The checks of ``spm check-estimator`` that call the plug-in, run in the plug-in's own process
(spm_model/bench/isolation.py, as ``spm train`` runs it): it gets the check set's training frames
and poses and its test frames as a camera gives them, shuffled as ``spm train`` shuffles them,
never a test label. It answers, one message each (isolation.encode): a ``call`` before every
call of the plug-in (the parent times each against --timeout), each ``check`` line, and the
``predictions`` to score (on the set, and after training on poses permuted against the images);
then ``end``. Nothing it sends is unpickled by the process that holds the labels."""

from __future__ import annotations

import numpy as np

from spm_model.bench.fitting import call_failure
from spm_model.bench.isolated_child import first_message, send
from spm_model.bench.plugin_refs import resolve
from spm_model.methods.registry import check_predictions


class ContractChecks:
    """The checks in order; each sends its line and says whether later ones can run."""

    def __init__(self, up, cls, frames, poses, camera):
        self.up, self.cls, self.frames, self.poses, self.camera = up, cls, frames, poses, camera
        self.name = cls.__name__
        self.deterministic = getattr(cls, "DETERMINISTIC", False) is True

    def call(self, what: str, fn, *args):
        """(value, None) or (None, why), the parent told first (its clock for --timeout starts)."""
        send(self.up, {"name": self.name, "kind": "call", "what": what})
        try:
            return fn(*args), None
        except BaseException as exc:  # noqa: BLE001 - SystemExit, KeyboardInterrupt too: a failed check
            return None, call_failure(exc)[:300]

    def add(self, ok, text: str, fix: str = "", note: bool = False) -> bool:
        status = "ok" if ok else ("note" if note else "FAIL")
        send(self.up, {"name": self.name, "kind": "check", "status": status,
                       "text": text if ok or not fix else f"{text}: {fix}"})
        return bool(ok)

    def construct(self):
        model, error = self.call("construct", self.cls)
        self.add(error is None, "constructs with no arguments", f"{error}; give every parameter a default")
        return model

    def params(self, model) -> None:
        if not callable(getattr(model, "get_params", None)):
            self.add(False, "get_params(): not defined (optional; the report records no parameters)", note=True)
            return
        params, error = self.call("get_params", model.get_params)
        if error is None and isinstance(params, dict):
            again, error = self.call("get_params", lambda: self.cls(**params).get_params())
            same = error is None and repr(again) == repr(params)
            self.add(same, "__init__ stores its parameters as given (get_params round trip)",
                     error or f"cls(**get_params()) gave {again!r}, not {params!r}; store each keyword as it is")
        else:
            self.add(False, "get_params() returns a dict", error or f"got {type(params).__name__}")

    def unfitted(self) -> None:
        model, error = self.call("construct", self.cls)
        _, error = self.call("predict", model.predict, self.camera) if model is not None else (None, error)
        self.add(error is not None, "predict before fit raises",
                 "it returned a result; raise an error until fit has run (spm_model.base.estimator.check_fitted)")

    def fit(self, model):
        poses = self.poses.copy()
        fitted, error = self.call("fit", model.fit, self.frames, poses)
        if error is not None:
            self.add(False, f"fit(frames, poses) on {len(self.frames)} frames", error)
            return None
        self.add(np.array_equal(poses, self.poses), "fit leaves the poses it was given unchanged",
                 "it modified its poses argument; copy before changing")
        ok = self.add(fitted is model, "fit returns self",
                      f"it returned {type(fitted).__name__}; end fit with `return self`")
        return model if ok else None

    def predict(self, model, frames=None):
        """The (n, 6) float64 predictions of ``frames`` (default the test frames), or (None, why)."""
        frames = self.camera if frames is None else frames
        raw, error = self.call("predict", model.predict, frames)
        if error is None:
            try:
                return check_predictions(self.name, raw, len(frames)), None
            except Exception as exc:  # noqa: BLE001 - its output could not be made an array
                return None, call_failure(exc)[:300]
        return None, error

    def predictions(self, model):
        out, error = self.predict(model)
        if not self.add(error is None, f"predict(frames) returns ({len(self.camera)}, 6) labels", error or ""):
            return None
        partial = int((np.isnan(out).any(axis=1) & ~np.isnan(out).all(axis=1)).sum())
        self.add(partial == 0, "rows are whole estimates or all NaN",
                 f"{partial} rows are part NaN; they count as no estimate where the data measures that part",
                 note=True)
        return out

    def repeat(self, model, out) -> None:
        again, error = self.predict(model)
        same = error is None and np.array_equal(again, out, equal_nan=True)
        promise = "; DETERMINISTIC promises it" if self.deterministic else ""
        self.add(same, "predict repeats (the same frames, the same labels)",
                 error or "a second call gave other labels" + promise, note=not self.deterministic)
        one, error = self.predict(model, self.camera[[0]])
        same = error is None and np.array_equal(one.reshape(-1), out[0], equal_nan=True)
        self.add(same, "a frame's label does not depend on the frames predicted with it",
                 error or "predicting frame 0 alone gave another label" + promise, note=not self.deterministic)
        empty, error = self.predict(model, self.camera[[]])
        self.add(error is None, "predict of no frames returns (0, 6)", error or "", note=True)

    def found(self, model) -> None:
        fn = getattr(model, "features_found", None)
        if not callable(fn):
            self.add(False, "features_found(frames): not defined (optional; reports show – for its feature "
                            "count)", note=True)
            return
        flags, error = self.call("features_found", fn, self.camera)
        ok = error is None and np.shape(flags) == (len(self.camera),)
        self.add(ok, "features_found(frames) returns one flag per frame",
                 error or f"got shape {np.shape(flags)}, expected ({len(self.camera)},)")

    def permuted(self, poses) -> None:
        """A fresh instance trained on ``poses`` permuted against the images: its predictions (to
        score against chance), or a note that it could not run."""
        model, error = self.call("construct", self.cls)
        if error is None:
            _, error = self.call("fit", model.fit, self.frames, poses.copy())
        out, error = self.predict(model) if error is None else (None, error)
        if error is not None:
            self.add(False, f"trained on poses permuted against the images: {error}", note=True)
            return
        send(self.up, {"name": self.name, "kind": "predictions", "set": "permuted"}, [out])


def serve_checks(down, up) -> None:
    """The child's work: ("checks", cls, frames, poses, camera frames, permuted poses)."""
    _, plugin, frames, poses, camera, permuted = first_message(down)
    try:
        cls = resolve(plugin)
    except BaseException as exc:  # noqa: BLE001 - its module's code, whatever it raised: one failed check
        send(up, {"name": plugin.__name__, "kind": "check", "status": "FAIL",
                  "text": f"imports: {call_failure(exc)}"})
        send(up, {"name": plugin.__name__, "kind": "end"})
        return
    checks = ContractChecks(up, cls, frames, poses, camera)
    checks.name = plugin.__name__   # what the parent expects each message to be about
    model = checks.construct()
    if model is not None:
        checks.params(model)
        checks.unfitted()
        model = checks.fit(model)
    out = checks.predictions(model) if model is not None else None
    if out is not None:
        checks.repeat(model, out)
        checks.found(model)
        send(up, {"name": checks.name, "kind": "predictions", "set": "test"}, [out])
        checks.permuted(permuted)
    send(up, {"name": checks.name, "kind": "end"})

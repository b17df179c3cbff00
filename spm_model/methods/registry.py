"""Every method the benchmark runs, behind one interface (scikit-learn's):
``fit(frames, poses)`` returns self, ``predict(frames)`` returns (n, 6) labels
(rx, ry, rz degrees, t metres; a row of NaN where the method has no estimate).
``frames`` is a sequence of per-frame dicts (spm_model/base/frames.py); poses (n, 6).
Learned state ends in ``_`` (each class's ``FITTED``); predict before fit raises
ModelError (spm_model/base/estimator.py).

Built in: SPM and KNN on its re-projected vectors (the paper's Tables 1 and 2),
the PCA- and LS-based raw-image baselines (§3.3-3.4), N3M and SMM (the paper's
Fig. 5 comparisons, spm_model/methods/n3m*.py and smm*.py), SIFT + PnP (N3M's matching
and robust PnP without its markers; ours, not in a paper: spm_model/methods/sift_pnp.py),
the reference template matcher (spm_model/methods/template.py), a small CNN trained on
the training frames with nearest-neighbour retrieval in its embedding (ours:
spm_model/methods/cnn.py; torch is the optional extra ``learn``) and chance (a random
training pose). Any class
with the same contract joins them: ``spm train --estimator MODULE:CLASS``
(docs/estimators.md).
"""

from __future__ import annotations

import importlib
import re
from dataclasses import dataclass
from typing import Callable

import numpy as np

from spm_model.errors import ModelError
from spm_model.methods.baselines import ChancePose, RawImagePose
from spm_model.methods.cnn import CNNPose
from spm_model.methods.n3m import N3MPose
from spm_model.methods.sift_pnp import SiftPnPPose
from spm_model.methods.smm import SMMPose
from spm_model.methods.spm_pose import SPMNeighbours, SPMPose
from spm_model.methods.template import TemplatePose
from spm_model.spm.features import FeatureConfig

@dataclass(frozen=True)
class Method:
    """One built-in method: its ``--methods`` name, its report title, how to make a fresh unfitted
    instance (``make(seed, features, params, spm)``; ``spm``: the run's SPMPose, which KNN shares),
    and, for a method whose model ``spm train`` saves, the model file, its title in the report and
    the class that reads it back (``from_model_file``; the file's header ``kind`` is ``name``).
    spm train fits that model on every training frame as a split makes the method (``make``, seed 0;
    spm_model/bench/final_models.py), one job per model after the splits, and writes it with the
    instance's ``save(path)``."""

    name: str
    title: str
    make: Callable
    model_file: str | None = None
    model_title: str | None = None
    model_class: Callable | None = None


def _spm_model_class():
    from spm_model.spm.estimator import SPMEstimator   # the model file holds the estimator on vectors

    return SPMEstimator


# The built-in methods in report order: every list of methods (names, titles, model files,
# what evaluate reads) is read from these rows. spm train hands the final-model jobs out in reverse
# order, meant as longest first: cnn, the slowest to fit, stays the last row with a model file.
METHODS = (
    Method("spm", "SPM", lambda seed, features, params, spm: spm, "model.npz", "SPM", _spm_model_class),
    Method("knn1", "KNN K=1", lambda seed, features, params, spm: SPMNeighbours(k=1, spm=spm)),
    Method("knn3", "KNN K=3", lambda seed, features, params, spm: SPMNeighbours(k=3, spm=spm)),
    Method("pca", "PCA-based", lambda seed, features, params, spm: RawImagePose(kind="pca")),
    Method("ls", "LS-based", lambda seed, features, params, spm: RawImagePose(kind="ls")),
    Method("n3m", "N3M (Hinterstoisser et al. 2007; marker levels only)", lambda seed, features, params,
           spm: N3MPose()),
    Method("sift-pnp", "SIFT + PnP (all matches; not in a paper)", lambda seed, features, params, spm: SiftPnPPose()),
    Method("smm", "SMM (Mei et al. 2011)", lambda seed, features, params, spm: SMMPose(seed=seed)),
    Method("template", "HOG templates (reference)", lambda seed, features, params, spm: TemplatePose(),
           "reference-model.npz", "HOG templates", lambda: TemplatePose),
    Method("cnn", "CNN embedding + HOG retrieval (ours)",
           lambda seed, features, params, spm: CNNPose(seed=seed, **params["cnn"]),
           "cnn-model.npz", "CNN", lambda: CNNPose),
    Method("chance", "chance (random training pose)", lambda seed, features, params, spm: ChancePose(seed=seed)),
)
BY_NAME = {m.name: m for m in METHODS}
METHOD_NAMES = {m.name: m.title for m in METHODS}
SAVED_MODELS = {m.name: m for m in METHODS if m.model_file}   # the methods whose model spm train writes


def check_method_names(names, what: str = "builtins") -> list | None:
    """``names`` (built-in method names; None: all) as a list; ModelError naming ``what`` (the
    argument, or the CLI's option), the unknown names (or an empty list) and the names to choose from."""
    if names is None:
        return None
    names = [names] if isinstance(names, str) else list(names)
    unknown = [n for n in names if n not in BY_NAME]
    if unknown or not names:
        raise ModelError(f"{what}: unknown {', '.join(map(str, unknown)) or 'empty list'}; choose from "
                         f"{', '.join(BY_NAME)}")
    return names


def builtin_methods(seed: int, features: FeatureConfig, model_params: dict | None = None) -> dict:
    """Fresh, unfitted instances of every built-in method, in report order. ``model_params``: SPM's
    parameters, but for its "cnn" entry: the cnn method's ({"device": "cuda"}, spm train --device)."""
    cnn = (model_params or {}).get("cnn") or {}
    if model_params and "cnn" in model_params:
        model_params = {k: v for k, v in model_params.items() if k != "cnn"}
    spm = SPMPose(seed=seed, features=features, params=model_params)
    return {m.name: m.make(seed, features, {**(model_params or {}), "cnn": cnn}, spm) for m in METHODS}


def load_estimator_class(spec: str):
    """'MODULE:CLASS' (MODULE importable, e.g. on PYTHONPATH) -> the class; ModelError otherwise."""
    match = re.fullmatch(r"([A-Za-z_][\w.]*):([A-Za-z_]\w*)", spec or "")
    if not match:
        raise ModelError(f"--estimator expects MODULE:CLASS (for example my_pose:MyEstimator), got {spec!r}")
    try:
        module = importlib.import_module(match.group(1))
    except BaseException as exc:  # noqa: BLE001 - a user's module can fail in any way (SystemExit too): one line
        if isinstance(exc, KeyboardInterrupt) and _user_interrupted():
            raise
        raise ModelError(f"--estimator {spec}: cannot import {match.group(1)} ({type(exc).__name__}: {exc}); "
                         "is its folder on PYTHONPATH?") from None
    cls = getattr(module, match.group(2), None)
    if cls is None or not all(callable(getattr(cls, m, None)) for m in ("fit", "predict")):
        raise ModelError(f"--estimator {spec}: {match.group(2)} is not a class in {match.group(1)} with "
                         "fit(frames, poses) and predict(frames)")
    return cls


def _user_interrupted() -> bool:
    """Whether the user's Ctrl-C (or SIGTERM) reached this command, as opposed to a plug-in raising it."""
    from spm_data.jobs.outcome import received

    return received() is not None


def check_predictions(name: str, pred, n: int) -> np.ndarray:
    """A method's predict() output as (n, 6) float64; ModelError naming the method otherwise."""
    try:
        out = np.asarray(pred, dtype=np.float64)
    except (TypeError, ValueError):
        out = None
    if out is None or out.shape != (n, 6):
        got = "something that is not an array" if out is None else f"shape {out.shape}"
        raise ModelError(f"estimator {name}: predict(frames) must return ({n}, 6) labels "
                         f"(rx, ry, rz degrees, t metres; NaN rows for no estimate), got {got}")
    return out

"""The models ``spm train`` saves: each built-in method whose registry row names a model file
(spm_model/methods/registry.py ``SAVED_MODELS``), fitted on every training frame as a split makes
it, and written by its own ``save(path)``. Nothing here names a method: a new row with a model
file is fitted, saved and read back (spm evaluate, spm predict) with no edit here."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from spm_model.base.frames import Frames
from spm_model.bench.feature_cache import FeatureTable
from spm_model.bench.fitting import failure, make_methods, unmet_needs
from spm_model.methods.registry import SAVED_MODELS


def saved_names(builtins) -> tuple:
    """The saved-model methods among ``builtins`` (None: all), in report order."""
    return tuple(name for name in SAVED_MODELS if builtins is None or name in builtins)


def fit_final_models(table: FeatureTable, model_params: dict, rows: np.ndarray, names) -> tuple[dict, dict]:
    """({name: fitted model or None}, {name: why it declined}) of the methods ``names`` fitted on the
    rows ``rows`` of ``table`` (protocols.final_rows), each made as a split makes it, with seed 0
    (fitting.make_methods; ``model_params`` holds "features"), one after another on one BLAS thread
    (as the splits: LAPACK's threaded solvers round differently). A method whose needs those frames
    do not meet, or whose fit raises, is None with its one-line reason; the others are still fitted."""
    from threadpoolctl import threadpool_limits

    fitted, declined = {}, {}
    for name, method in make_methods(0, model_params, list(names)).items():
        fitted[name], why = None, unmet_needs(method, table, rows)
        if why is None:
            try:
                with threadpool_limits(limits=1, user_api="blas"):
                    fitted[name] = method.fit(Frames(table, rows), table.pose[rows])
            except Exception as exc:  # noqa: BLE001 - as in the splits: the other models are still written
                why = failure(exc)
        if why is not None:
            declined[name] = why
    return fitted, declined


def save_final_models(fitted: dict, out: Path) -> dict:
    """{name: path} of the models in ``fitted`` written to their row's file in ``out``; the file of
    every other saved-model method (not asked for, or declined) removed where an earlier run left
    one, so the folder never pairs this report with another run's model."""
    written = {}
    for name, row in SAVED_MODELS.items():
        path = out / row.model_file
        if fitted.get(name) is not None:
            written[name] = fitted[name].save(path)
        else:
            path.unlink(missing_ok=True)
            path.with_suffix(".safetensors").unlink(missing_ok=True)   # a cnn model's weights beside it
    return written


def training_costs(fitted: dict) -> dict:
    """{name: what its training cost} of the fitted models that record it (``training_``: cnn's
    seconds, steps, epochs, frames, device), for the report's context."""
    return {name: model.training_ for name, model in fitted.items()
            if model is not None and getattr(model, "training_", None) is not None}

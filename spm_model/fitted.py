"""The model error type and the one fitted check every estimator uses (scikit-learn style).

An estimator is fitted when it has all of its learned attributes (names ending
in ``_``), set by ``fit`` or by the class's ``from_state`` / ``load``. Its
``predict``, ``transform``, ``save`` (and any other method that needs the learned
state) start with ``check_fitted(self, ATTRIBUTES)``, which raises ModelError
naming the class and the fix; no unfitted estimator fails another way.
"""

from __future__ import annotations

import inspect

from spm_data.errors import SpmError


class ModelError(SpmError):
    """A model cannot be trained, loaded or applied to this input."""


def is_fitted(estimator, attributes) -> bool:
    """Whether ``estimator`` has every learned attribute in ``attributes`` (names ending in ``_``)."""
    return all(hasattr(estimator, name) for name in attributes)


def _fit_call(cls) -> str:
    """'fit(X, y)': the class's fit signature as the message shows it."""
    try:
        names = [p for p in inspect.signature(cls.fit).parameters if p != "self"]
    except (AttributeError, TypeError, ValueError):
        return "fit(...)"
    return f"fit({', '.join(names)})"


def check_fitted(estimator, attributes) -> None:
    """ModelError unless ``estimator`` has every learned attribute in ``attributes``:
    "this SPMEstimator is not fitted yet; call fit(X, y) first, or load a model file
    with SPMEstimator.load(path)" (the load hint only for classes with ``load``)."""
    missing = [name for name in attributes if not hasattr(estimator, name)]
    if not missing:
        return
    cls = type(estimator)
    name = cls.__name__
    partial = f" ({', '.join(missing)} not set)" if len(missing) < len(attributes) else ""
    load = f", or load a model file with {name}.load(path)" if callable(getattr(cls, "load", None)) else ""
    raise ModelError(f"this {name} is not fitted yet{partial}; call {_fit_call(cls)} first{load}")

"""The one estimator contract every method follows, built in or plug-in (scikit-learn's).

- ``__init__`` takes keyword-only parameters and only stores them (no
  validation, no work): ``get_params`` reads them back by the signature's names.
- ``fit(frames, poses)`` learns from a sequence of frames (spm_model/base/frames.py)
  and their (n, 6) poses (rx, ry, rz degrees, t metres) and returns ``self``.
- ``predict(frames)`` returns (n, 6) labels of the same kind; a row of NaN is a
  frame without an estimate (scored as a failure).
- Learned state ends in ``_`` and is listed in the class's ``FITTED``; every
  method that needs it starts with ``self.check_fitted()`` (one check,
  :func:`check_fitted`), so an unfitted estimator fails with one ModelError.
- ``from_state(**params_and_learned)`` builds the fitted estimator ``fit`` would
  have left (model files load through it).
- ``DETERMINISTIC = True`` (a class attribute, default False) promises that fit and
  predict use no seed and no random choice, and that a frame's prediction does not depend
  on the other frames predicted with it: the benchmark then fits the method once when
  every run has the same splits (loco, offgrid) and reuses its predictions in the other
  runs (spm_model/bench/protocols.py).

- ``NEEDS`` (a class attribute, a :class:`Needs`, default ``Needs()``) declares what the method
  needs of its training frames: the benchmark checks it before ``fit`` and reports the method as
  *declined*, with the reason, where the data does not have it (spm_model/bench/protocols.py);
  a ``fit`` that raises is declined the same way, and the other methods run on.
- ``features_found(frames)`` (optional) returns (n,) bool: the frames the method found its
  features on (keypoints, a descriptor); every report counts them per method.

A plug-in (``spm train --estimator MODULE:CLASS``) need not subclass
:class:`PoseEstimator`; it needs ``fit`` and ``predict`` with this contract
(``spm check-estimator MODULE:CLASS`` checks it).
"""

from __future__ import annotations

import inspect
from abc import ABC, abstractmethod
from dataclasses import dataclass, fields

from spm_model.errors import ModelError


@dataclass(frozen=True)
class Needs:
    """What a method needs of its training frames (class attribute ``NEEDS``).

    frames: training frames, at least. depth: training frames with a measured depth under the
    object (renders, BOP, captures with depth images; not COIL or plain photos). spm_features:
    training frames with SPM's training features (keypoints enough for its ellipse), at least.
    sequences: camera paths (a shard's instance: frames of one object along one walk or capture)
    among the training frames, at least."""

    frames: int = 1
    depth: bool = False
    spm_features: int = 0
    sequences: int = 1

    def __post_init__(self):
        for f in fields(self):
            value, flag = getattr(self, f.name), f.type in (bool, "bool")
            ok = isinstance(value, bool) if flag else (type(value) is int and value >= 0)
            if not ok:
                want = "True or False" if flag else "a whole number >= 0"
                raise ModelError(f"Needs.{f.name} must be {want}, got {value!r}")


def needs_of(cls) -> Needs:
    """The :class:`Needs` a method class (or instance) declares (``Needs()`` when it declares
    none); ModelError when ``NEEDS`` is something else."""
    needs = getattr(cls, "NEEDS", None)
    if needs is None:
        return Needs()
    if not isinstance(needs, Needs):
        name = getattr(cls, "__name__", type(cls).__name__)
        raise ModelError(f"{name}.NEEDS must be a spm_model.base.estimator.Needs, got {type(needs).__name__}; "
                         "declare NEEDS = Needs(depth=True, ...) or leave it out")
    return needs


def is_fitted(estimator, attributes) -> bool:
    """Whether ``estimator`` has every learned attribute in ``attributes`` (names ending in ``_``)."""
    return all(hasattr(estimator, name) for name in attributes)


def _fit_call(cls) -> str:
    """'fit(frames, poses)': the class's fit signature as the message shows it."""
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


class Estimator:
    """What every estimator class shares, whatever its fit signature: parameters
    read back from the signature, one fitted check, ``from_state``, a readable repr."""

    FITTED: tuple = ()
    DETERMINISTIC: bool = False
    NEEDS: Needs = Needs()

    @classmethod
    def _param_names(cls) -> list:
        return [p.name for p in inspect.signature(cls.__init__).parameters.values()
                if p.kind == p.KEYWORD_ONLY]

    def get_params(self) -> dict:
        """The constructor's parameters, in its order (scikit-learn's get_params)."""
        return {name: getattr(self, name) for name in self._param_names()}

    def is_fitted(self) -> bool:
        return is_fitted(self, self.FITTED)

    def check_fitted(self) -> None:
        check_fitted(self, self.FITTED)

    @classmethod
    def from_state(cls, **values):
        """The fitted estimator with these parameters (names of the constructor) and
        learned attributes (names ending in ``_``), as ``fit`` would leave it; ModelError
        naming what is unknown or missing."""
        learned = {k: v for k, v in values.items() if k.endswith("_")}
        params = {k: v for k, v in values.items() if not k.endswith("_")}
        unknown = sorted(set(params) - set(cls._param_names())) + sorted(set(learned) - set(cls.FITTED))
        if unknown:
            raise ModelError(f"{cls.__name__}.from_state: unknown {', '.join(unknown)}; expected parameters "
                             f"{cls._param_names()} and learned {list(cls.FITTED)}")
        model = cls(**params)
        for name, value in learned.items():
            setattr(model, name, value)
        model.check_fitted()
        return model

    def __repr__(self) -> str:
        params = ", ".join(f"{k}={v!r}" for k, v in self.get_params().items())
        return f"{type(self).__name__}({params})"


class PoseEstimator(Estimator, ABC):
    """Base of the benchmark's methods: ``fit(frames, poses)`` -> self, ``predict(frames)``
    -> (n, 6). Subclasses set ``FITTED`` and implement both."""

    @abstractmethod
    def fit(self, frames, poses) -> "PoseEstimator":
        """Learn from frames and their (n, 6) poses; return self."""

    @abstractmethod
    def predict(self, frames):
        """(n, 6) labels of ``frames``: rx, ry, rz degrees, t metres; NaN rows for no estimate."""

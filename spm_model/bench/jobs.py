"""The benchmark's jobs, as the executors carry them to workers (protocols.bench_job runs them)."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class SplitJob:
    """One (run, split) of a protocol: every method (``builtins``: their names, None: all; ``estimators``:
    {name: plug-in}) fitted on the split's training frames and asked about its test frames.
    ``source``: where a worker reads the feature table (protocols._table); ``timeout``: seconds per
    plug-in call, or None."""

    source: object
    protocol: str
    run: int
    index: int
    model_params: dict
    builtins: list | None
    estimators: dict | None
    train_occluded: bool
    timeout: float | None


@dataclass(frozen=True)
class FinalJob:
    """The models ``spm train`` saves, of the methods ``wanted`` names, fitted on every training frame
    (final_models.fit_final_models)."""

    source: object
    model_params: dict
    train_occluded: bool
    wanted: tuple

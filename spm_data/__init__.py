"""spm_data: labelled 6-DoF pose datasets (meshes -> camera paths -> renders -> HDF5 shards).

The public face, for a notebook (docs/architecture.md, "From a notebook"): ``load_run_specs`` and
``render_dataset`` (render specs into a folder), ``occlude_dataset``, ``open_folder``, ``read_shard``,
``ShardDataset`` (a folder as a dataset for training loops), ``make_executor``, and the errors.
Everything but the errors is imported on first use, so ``import spm_data`` stays light.

One folder per layer, lowest first (docs/architecture.md; tests/system/test_layers.py
keeps imports downward): ``io`` (shards, folders, locks, files, images), ``core``
(conventions, camera paths, meshes, specs), ``render`` (the Renderer interface; bpy
and OpenGL load only in its backends), ``jobs`` (executors, resumable runs, progress),
``formats`` (other datasets in and out), ``pipelines`` (the work of each spm-data command).
"""

import importlib

from spm_data.errors import MeshError, RenderError, ShardError, SpecError, SpmError
from spm_data.version import __version__

# name -> the module it lives in, imported on first use (PEP 562).
PUBLIC = {"load_run_specs": "spm_data.pipelines.render_jobs", "render_dataset": "spm_data.pipelines.render_jobs",
          "occlude_dataset": "spm_data.pipelines.occlude_jobs", "open_folder": "spm_data.io.folders",
          "read_shard": "spm_data.io.shards", "ShardDataset": "spm_data.io.loaders",
          "make_executor": "spm_data.jobs"}


def __getattr__(name):
    if name not in PUBLIC:
        raise AttributeError(f"module 'spm_data' has no attribute {name!r}")
    value = getattr(importlib.import_module(PUBLIC[name]), name)
    globals()[name] = value
    return value


__all__ = ["SpmError", "SpecError", "MeshError", "ShardError", "RenderError", "__version__", *PUBLIC]

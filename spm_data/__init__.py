"""spm_data: labelled 6-DoF pose datasets (meshes -> camera paths -> renders -> HDF5 shards).

One folder per layer, lowest first (docs/architecture.md; tests/system/test_layers.py
keeps imports downward): ``io`` (shards, folders, locks, files, images), ``core``
(conventions, camera paths, meshes, specs), ``render`` (the Renderer interface; bpy
and OpenGL load only in its backends), ``jobs`` (executors, resumable runs),
``formats`` (other datasets in and out), ``commands`` (what each spm-data command does).
"""

__version__ = "0.1.0"

from spm_data.errors import MeshError, RenderError, ShardError, SpecError, SpmError

__all__ = ["SpmError", "SpecError", "MeshError", "ShardError", "RenderError", "__version__"]

"""spm_data: labelled 6-DoF pose datasets (meshes -> camera paths -> renders -> HDF5 shards).

Layers (see docs/architecture.md): the pure-numpy core (``poses``, ``paths``,
``meshes``, ``specs``, ``shards``) imports no ``bpy`` and no OpenGL; renderers
live in ``spm_data.render`` and are imported lazily by name.
"""

__version__ = "0.1.0"

from spm_data.errors import MeshError, RenderError, ShardError, SpecError, SpmError

__all__ = ["SpmError", "SpecError", "MeshError", "ShardError", "RenderError", "__version__"]

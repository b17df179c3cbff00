"""Which mesh each frame of a shard shows, by digest (mesh_store.py), for shards of any age.

A shard written since the store exists names its target's digest per frame (field ``mesh``) and
its distractors' (attribute ``distractor_mesh_digests``); the meshes are in its folder's
``meshes/`` (for a synthetic shard copied without them, rebuilt from its spec: used only when the
rebuilt mesh has the digest the frame names). An older synthetic shard names none: its meshes are rebuilt from the spec
and seed
it recorded (instances.shard_mesh, distractors.pool_mesh), digested, and kept in memory, so
merge and export treat both alike. Imported frames have no mesh: digest "".
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from spm_data.errors import MeshError
from spm_data.core.distractors import pool_mesh
from spm_data.core.instances import shard_mesh
from spm_data.core.mesh_store import has_mesh, load_mesh, mesh_digest, save_mesh


def store_pool(spec, folder, used: np.ndarray) -> list[str]:
    """Store the spec's distractor meshes that ``used`` (any shape, pool indices, -1 none) names;
    returns the digest of every pool index ("" for those unused)."""
    indices = {int(k) for k in np.ravel(used) if k >= 0}
    size = max(indices, default=-1) + 1
    return [save_mesh(folder, pool_mesh(spec, k)) if k in indices else "" for k in range(size)]


class FrameMeshes:
    """The meshes of the frames of shards in one folder (``folder``); ``spec_dir``: where a
    mesh-file spec's files are when not where the shards recorded (export bop --meshes-from)."""

    def __init__(self, folder, spec_dir=None):
        self.folder, self.spec_dir = Path(folder), spec_dir
        self.rebuilt: dict[str, object] = {}   # digest -> mesh: rebuilt (shards older than the store) or read

    def targets(self, attrs: dict, data: dict) -> list[str]:
        """The target's digest of every frame of ``data`` (read with ``instance_id`` and, when the
        shard has it, ``mesh``); "" for a frame without a mesh."""
        if "mesh" in data:
            named = [str(d) for d in data["mesh"]]
            missing = {int(i) for i, d in zip(data["instance_id"], named)
                       if d and d not in self.rebuilt and not has_mesh(self.folder, d)}
            if missing and attrs.get("source") == "synthetic":   # a shard copied without its store:
                try:                                              # rebuilt from its spec, if it still is that mesh
                    self._rebuild(attrs, missing)
                except MeshError:
                    pass   # its mesh file is gone too: mesh() says the store lacks it
            return named
        return [self._rebuild(attrs, {int(i) for i in data["instance_id"]})[int(i)] for i in data["instance_id"]]

    def _rebuild(self, attrs: dict, instances: set) -> dict[int, str]:
        by_instance: dict[int, str] = {}
        for inst in sorted(instances):
            mesh = shard_mesh(attrs, inst, spec_dir=self.spec_dir)
            by_instance[inst] = self._remember(mesh) if mesh is not None else ""
        return by_instance

    def pool(self, attrs: dict) -> list[str]:
        """The digest of every index of the shard's distractor pool ("" where unknown or unused)."""
        if attrs.get("distractor_mesh_digests"):
            return [str(d) for d in json.loads(attrs["distractor_mesh_digests"])]
        if not attrs.get("distractor_meshes") or attrs.get("source") != "synthetic":
            return []
        from spm_data.core.specs import shard_spec

        spec = shard_spec(attrs)
        return [self._remember(pool_mesh(spec, k)) for k in range(len(json.loads(attrs["distractor_meshes"])))]

    def _remember(self, mesh) -> str:
        digest = mesh_digest(mesh)
        self.rebuilt.setdefault(digest, mesh)
        return digest

    def mesh(self, digest: str):
        """The mesh ``digest`` (None for ""): rebuilt in this process, or from the folder's store."""
        if not digest:
            return None
        if digest not in self.rebuilt:   # kept: an export meets each mesh in many frames
            self.rebuilt[digest] = load_mesh(self.folder, digest)
        return self.rebuilt[digest]

    def carry(self, digests, folder) -> None:
        """Put the meshes ``digests`` into ``folder``'s store (verified on the way)."""
        for digest in sorted(set(digests) - {""}):
            if not has_mesh(folder, digest):
                save_mesh(folder, self.mesh(digest))

"""Object instances of a spec: which mesh each one is, and the exact mesh a shard was rendered from.

A procedural instance is rebuilt from its class, seed and index. A mesh file is
recorded in each shard that renders it (``mesh_files`` attribute: instance ->
path relative to the spec's folder and the file's sha256), with the spec's
folder (``spec_dir``), so anything that rebuilds it later (the BOP export, the
surface metrics) reads that same file from wherever it runs, and refuses a
file that has changed since.
"""

from __future__ import annotations

import glob
import json
import os
from functools import lru_cache
from pathlib import Path

from spm_data.errors import MeshError, SpecError
from spm_data.core.mesh_files import load_mesh_file
from spm_data.core.shapes import procedural_mesh
from spm_data.core.symmetries import declared_symmetries
from spm_data.io.files import file_sha256
from spm_data.core.specs import RenderSpec

# The shard attributes a rendered mesh is rebuilt from.
MESH_ATTRS = ("source", "spec", "seed", "spec_dir", "mesh_files")


def mesh_files(spec: RenderSpec) -> list[Path]:
    """The spec's mesh files (globs relative to the spec file), sorted, de-duplicated."""
    found: list[Path] = []
    for pattern in spec.mesh.files:
        full = pattern if Path(pattern).is_absolute() else str(Path(spec.base_dir) / pattern)
        matches = sorted(Path(p) for p in glob.glob(full, recursive=True))
        if not matches:
            raise SpecError(f"mesh.files: {pattern!r} matches no file (relative to {spec.base_dir})")
        found += [m for m in matches if m not in found]
    return found


def instance_count(spec: RenderSpec) -> int:
    return spec.mesh.instances if spec.mesh.source == "procedural" else len(mesh_files(spec))


@lru_cache(maxsize=8)
def load_instance(spec: RenderSpec, instance: int):
    """The TexturedMesh of ``instance`` (cached per process: frames arrive grouped by instance)."""
    m = spec.mesh
    if m.source == "procedural":
        return procedural_mesh(m.generator or spec.class_name, instance, seed=spec.seed, size=m.size)
    return load_mesh_file(mesh_files(spec)[instance], size=m.size, seed=spec.seed, instance=instance,
                          texture=m.texture, symmetries=declared_symmetries(m.symmetries), up=m.up)


@lru_cache(maxsize=256)
def _hash(path: str, size: int, mtime_ns: int) -> str:
    return file_sha256(path)


def content_hash(path) -> str:
    """sha256 of a file, cached while its size and modification time stay the same."""
    st = os.stat(path)
    return _hash(str(path), st.st_size, st.st_mtime_ns)


def mesh_record(spec: RenderSpec, instance: int) -> dict | None:
    """``{"path": relative to the spec's folder, "sha256": ...}`` for a mesh-file instance, None
    for a procedural one."""
    if spec.mesh.source == "procedural":
        return None
    path = mesh_files(spec)[instance]
    return {"path": Path(os.path.relpath(path, spec.base_dir)).as_posix(), "sha256": content_hash(path)}


def mesh_attrs(spec: RenderSpec, records: dict) -> dict:
    """The shard attributes that name a shard's mesh files (empty for procedural specs, so
    their shards stay the same bytes wherever they are rendered)."""
    if spec.mesh.source == "procedural":
        return {}
    return {"spec_dir": str(Path(spec.base_dir).resolve()),
            "mesh_files": json.dumps({str(k): v for k, v in sorted(records.items())}, sort_keys=True)}


def shard_mesh(attrs: dict, instance_id: int, spec_dir=None):
    """The TexturedMesh a synthetic shard's frame was rendered from (rebuilt from the
    spec and seed in the shard's attributes), or None for other sources.

    Mesh files resolve against ``spec_dir`` (default: the spec's folder the shard
    recorded); MeshError naming both paths when the file is missing or its
    content differs from what was rendered."""
    if attrs.get("source") != "synthetic" or not attrs.get("spec"):
        return None
    from spm_data.core.specs import shard_spec

    spec = shard_spec(attrs)
    if spec.mesh.source == "procedural":
        return load_instance(spec, instance_id)
    record = json.loads(attrs.get("mesh_files") or "{}").get(str(instance_id))
    if record is None or not attrs.get("spec_dir"):
        raise MeshError(f"the shard does not record which file instance {instance_id} was rendered from "
                        "(made by an older spm); render it again to export or score its meshes")
    folder = Path(spec_dir or attrs["spec_dir"])
    path = folder / record["path"]
    where = f"{record['path']!r} relative to the spec folder {folder}"
    if not path.is_file():
        raise MeshError(f"mesh file {path} not found ({where}, as rendered); put the meshes back "
                        "or give the spec's folder (export bop --meshes-from)")
    actual = content_hash(path)
    if actual != record["sha256"]:
        raise MeshError(f"mesh file {path} ({where}) has changed since it was rendered "
                        f"(sha256 {actual[:12]}…, rendered from {record['sha256'][:12]}…); "
                        "restore that file or render again")
    return _load_recorded(spec.replace(base_dir=str(folder)), str(path), instance_id)


@lru_cache(maxsize=8)
def _load_recorded(spec: RenderSpec, path: str, instance: int):
    m = spec.mesh
    return load_mesh_file(path, size=m.size, seed=spec.seed, instance=instance, texture=m.texture,
                          symmetries=declared_symmetries(m.symmetries), up=m.up)

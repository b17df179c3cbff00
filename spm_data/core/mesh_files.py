"""Mesh files: user meshes (.obj .ply .stl .glb .gltf .off) read through trimesh into a TexturedMesh."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import trimesh

from spm_data.errors import MeshError, one_line
from spm_data.core.meshes import TexturedMesh, instance_rng, to_textured
from spm_data.core.poses import GLTF_TO_OBJECT
from spm_data.core.symmetries import NO_SYMMETRY, Symmetries

MESH_SUFFIXES = (".obj", ".ply", ".stl", ".glb", ".gltf", ".off")
GLTF_SUFFIXES = (".glb", ".gltf")


UP_AXES = ("z", "y")


def load_mesh_file(path, size: float = 0.25, seed: int = 0, instance: int = 0,
                   texture: str = "auto", symmetries: Symmetries = NO_SYMMETRY, up: str = "z") -> TexturedMesh:
    """Load a user mesh (.obj .ply .stl .glb .gltf .off) through trimesh.

    Multi-part files are concatenated; non-watertight meshes are fine. glTF
    files (+y up, front +z) are turned into the object frame (+z up, front +x)
    by poses.GLTF_TO_OBJECT; so are other files with ``up = "y"`` (the spec's
    mesh.up), which are otherwise taken as they are (+z up, front +x).
    texture: ``"auto"`` keeps the file's own image texture when it has one (trimesh's
    2x2 placeholder of one colour, for a file with UVs and no image, is none), ``"procedural"`` always paints a seeded
    procedural
    one. symmetries: the shape's, as the spec declares them (declared_symmetries).
    """
    path = Path(path)
    if texture not in ("auto", "procedural"):
        raise MeshError(f"texture must be 'auto' or 'procedural', got {texture!r}")
    if up not in UP_AXES:
        raise MeshError(f"up must be 'z' or 'y', got {up!r}")
    if not path.is_file():
        raise MeshError(f"mesh file not found: {path}")
    if path.suffix.lower() not in MESH_SUFFIXES:
        raise MeshError(f"{path}: unsupported mesh type {path.suffix!r}; expected one of {' '.join(MESH_SUFFIXES)}")
    if path.stat().st_size == 0:
        raise MeshError(f"{path}: file is empty")
    try:
        loaded = trimesh.load(str(path), force="mesh", process=False)
    except Exception as exc:  # trimesh raises many types for bad files
        raise MeshError(f"{path}: not a readable mesh; trimesh could not parse it as {path.suffix.lower()} "
                        f"({type(exc).__name__}: {one_line(exc) or 'no detail'})") from None
    if isinstance(loaded, list):
        loaded = trimesh.util.concatenate(loaded) if loaded else None
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0:
        raise MeshError(f"{path}: mesh has no faces")
    if not np.all(np.isfinite(loaded.vertices)):
        raise MeshError(f"{path}: mesh has non-finite vertex coordinates")
    faces = np.asarray(loaded.faces)
    if faces.min() < 0 or faces.max() >= len(loaded.vertices):
        bad = faces.min() if faces.min() < 0 else faces.max()
        raise MeshError(f"{path}: not a readable mesh; a face refers to vertex {bad}, the file has "
                        f"{len(loaded.vertices)} vertices")
    loaded.remove_unreferenced_vertices()
    if path.suffix.lower() in GLTF_SUFFIXES or up == "y":
        turn = np.eye(4)
        turn[:3, :3] = GLTF_TO_OBJECT
        loaded.apply_transform(turn)
    rng = instance_rng(seed, path.stem, instance)
    mesh = to_textured(loaded, path.stem, size, rng, keep_texture=(texture == "auto"))
    return replace(mesh, symmetries=symmetries)

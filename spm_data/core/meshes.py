"""Meshes: the render-ready :class:`TexturedMesh` and how any mesh becomes one.

Every mesh leaves spm_data.core as a :class:`TexturedMesh` in the object frame of
poses.py (bounding box centred on the origin, ``+z`` up, front towards ``+x``,
longest side scaled to ``size`` metres), with per-corner UVs and a texture
image, so any renderer can draw it and SIFT finds keypoints on the renders.
The built-in classes are in shapes.py, mesh files are read by mesh_files.py;
both end in :func:`to_textured` here.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass

import numpy as np
import trimesh

from spm_data.errors import MeshError
from spm_data.core.symmetries import NO_SYMMETRY, Symmetries
from spm_data.core.textures import procedural_texture

_SMOOTH_ANGLE_DEG = 35.0  # corners whose faces bend less than this share a normal


@dataclass(frozen=True, eq=False)
class TexturedMesh:
    """A render-ready mesh.

    vertices (V, 3) float64 metres, object frame; faces (F, 3) int64;
    normals (V, 3) float64 unit; uv (V, 2) float64 in [0, 1] with v = 0 at the
    image's bottom row (OpenGL / Blender / trimesh); texture (H, W, 3) uint8;
    symmetries: the shape's own (exact for built-in classes, declared in the
    spec for mesh files).
    """

    name: str
    vertices: np.ndarray
    faces: np.ndarray
    normals: np.ndarray
    uv: np.ndarray
    texture: np.ndarray
    symmetries: Symmetries = NO_SYMMETRY

    def to_trimesh(self) -> trimesh.Trimesh:
        from PIL import Image

        visual = trimesh.visual.TextureVisuals(uv=self.uv, image=Image.fromarray(self.texture))
        return trimesh.Trimesh(self.vertices, self.faces, vertex_normals=self.normals,
                               visual=visual, process=False)

    @property
    def extents(self) -> np.ndarray:
        """(3,) float64 metres: bounding-box side lengths."""
        return self.vertices.max(axis=0) - self.vertices.min(axis=0)


# --------------------------------------------------------------------------- normalising, UVs, normals

def normalise(mesh: trimesh.Trimesh, size: float) -> trimesh.Trimesh:
    """Centre the bounding box on the origin and scale the longest side to ``size`` metres."""
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    longest = float((hi - lo).max())
    if not np.isfinite(longest) or longest <= 0:
        raise MeshError(f"mesh has zero or non-finite extent ({longest}); it cannot be scaled")
    mesh = mesh.copy()
    mesh.vertices = (vertices - (lo + hi) / 2.0) * (size / longest)
    return mesh


def diameter(points) -> float:
    """Largest distance between two of ``points`` (N, 3), in their units (over the convex hull)."""
    points = np.asarray(points, dtype=np.float64)
    hull = trimesh.Trimesh(points, process=False).convex_hull.vertices if len(points) > 3 else points
    return float(np.max(np.linalg.norm(hull[:, None] - hull[None], axis=2)))


def _corner_normals(mesh: trimesh.Trimesh) -> np.ndarray:
    """(F*3, 3) normals per face corner: averaged over neighbouring faces that
    bend less than _SMOOTH_ANGLE_DEG, so spheres look round and boxes keep edges."""
    fn = np.asarray(mesh.face_normals)
    area = np.asarray(mesh.area_faces)
    vf = np.asarray(mesh.vertex_faces)  # (V, max valence), padded with -1
    cand = vf[mesh.faces.reshape(-1)]  # (3F, valence)
    own = np.repeat(np.arange(len(fn)), 3)
    valid = cand >= 0
    cn = fn[np.where(valid, cand, 0)]
    close = np.einsum("ckd,cd->ck", cn, fn[own]) > np.cos(np.radians(_SMOOTH_ANGLE_DEG))
    w = (area[np.where(valid, cand, 0)] * (valid & close))[..., None]
    n = (cn * w).sum(axis=1)
    norm = np.linalg.norm(n, axis=1, keepdims=True)
    return np.where(norm > 1e-12, n / np.maximum(norm, 1e-12), fn[own])


def _box_projected_uv(corners: np.ndarray, face_normals: np.ndarray, size: float) -> np.ndarray:
    """(F*3, 2) UVs: each face is projected along its dominant normal axis into
    one of six tiles (+x -x +y -y +z -z) of a 3 x 2 atlas."""
    fn = np.repeat(face_normals, 3, axis=0)
    axis = np.abs(fn).argmax(axis=1)
    sign = np.take_along_axis(fn, axis[:, None], axis=1)[:, 0] >= 0
    tile = axis * 2 + (~sign)
    # The two remaining axes, in [0, 1] over the normalised bounding box.
    other = np.array([[1, 2], [0, 2], [0, 1]])[axis]
    coords = np.take_along_axis(corners, other, axis=1) / size + 0.5
    coords = np.clip(coords, 0.0, 1.0) * 0.96 + 0.02  # a margin so filtering never bleeds across tiles
    col, row = tile % 3, tile // 3
    return np.column_stack([(col + coords[:, 0]) / 3.0, (row + coords[:, 1]) / 2.0])


def to_textured(mesh: trimesh.Trimesh, name: str, size: float, rng: np.random.Generator,
                keep_texture: bool = False) -> TexturedMesh:
    """Normalise ``mesh`` and give it UVs and a texture (its own if ``keep_texture``
    and it has an image texture with UVs, else a seeded procedural one; a 2x2 image
    of one colour is trimesh's placeholder for UVs without an image, so none)."""
    mesh = normalise(mesh, size)
    visual = getattr(mesh, "visual", None)
    own_image = None
    if keep_texture and isinstance(visual, trimesh.visual.TextureVisuals) and visual.uv is not None:
        image = getattr(visual.material, "baseColorTexture", None) or getattr(visual.material, "image", None)
        if image is not None:
            own_image = np.asarray(image.convert("RGB"), dtype=np.uint8)
            if own_image.shape[0] * own_image.shape[1] <= 4 and (own_image == own_image[:1, :1]).all():
                own_image = None  # trimesh's 2x2 placeholder of one colour for UVs without an image
    faces = np.asarray(mesh.faces, dtype=np.int64)
    if own_image is not None:
        uv = np.asarray(visual.uv, dtype=np.float64)[faces.reshape(-1)]
        texture = own_image
    else:
        uv = None
        texture = procedural_texture(rng)
    corners = np.asarray(mesh.vertices, dtype=np.float64)[faces.reshape(-1)]
    if uv is None:
        uv = _box_projected_uv(corners, np.asarray(mesh.face_normals), size)
    return TexturedMesh(name=name, vertices=corners, faces=np.arange(len(corners), dtype=np.int64).reshape(-1, 3),
                        normals=_corner_normals(mesh), uv=uv, texture=texture)


def instance_rng(seed: int, class_name: str, instance: int) -> np.random.Generator:
    """The generator for one instance: stable across runs, processes and machines."""
    return np.random.default_rng([int(seed), zlib.crc32(class_name.encode()), int(instance)])

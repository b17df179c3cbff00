"""Silhouettes in numpy: which pixel centres a posed mesh covers.

The distractor placement (spm_data.core.distractors) needs a target's and a
distractor's silhouettes many times a frame, before anything is rendered and
the same for every renderer, so it rasterises here rather than in OpenGL or
Blender. Both renderers sample coverage at the pixel centres K describes (one
sample a pixel), which is what this module does, so their masks match it up to
pixel centres lying on a triangle edge (tests/core/test_raster.py measures it).
"""

from __future__ import annotations

import numpy as np

from spm_data.errors import SpmError

NEAR = 1e-3          # metres: a vertex closer to the camera plane than this is not projected
CLIP_NEAR, CLIP_FAR = 0.01, 100.0  # metres: both renderers' clipping planes; placement keeps distractors beyond
_CANDIDATES = 1 << 21  # pixel-centre tests per batch of triangles (memory bound)


def project(vertices, K, R, t) -> tuple[np.ndarray, np.ndarray]:
    """Object-frame ``vertices`` (N, 3) metres -> (``uv`` (N, 2) float64 pixels,
    OpenCV centres; ``z`` (N,) float64 metres along the camera's z axis), for the
    pose ``R`` (3, 3), ``t`` (3,) (object to camera, OpenCV) and ``K`` (3, 3)."""
    cam = np.asarray(vertices, dtype=np.float64) @ np.asarray(R, dtype=np.float64).T + np.asarray(t, dtype=np.float64)
    z = cam[:, 2]
    uvw = cam @ np.asarray(K, dtype=np.float64).T
    with np.errstate(divide="ignore", invalid="ignore"):
        return uvw[:, :2] / uvw[:, 2:3], z


def silhouette(vertices, faces, K, R, t, height: int, width: int) -> np.ndarray:
    """(height, width) bool: the pixel centres covered by the mesh ``vertices`` (N, 3)
    metres, ``faces`` (F, 3) int, posed by ``R``, ``t`` (object to camera, OpenCV)
    and seen through ``K`` (3, 3, OpenCV pixel centres). Both faces of every
    triangle count; a centre on an edge counts. Triangles with a vertex behind
    ``NEAR`` are an error (placement keeps every object in front of the camera)."""
    uv, z = project(vertices, K, R, t)
    tri_faces = np.asarray(faces, dtype=np.int64)
    if np.any(z[tri_faces] < NEAR):
        raise SpmError("silhouette: a triangle reaches behind the camera; keep the mesh in front of it")
    tri = uv[tri_faces]                                   # (F, 3, 2)
    out = np.zeros((height, width), dtype=bool)
    lo = np.ceil(tri.min(axis=1) - 1e-9).astype(np.int64)   # first pixel centre inside each bbox
    hi = np.floor(tri.max(axis=1) + 1e-9).astype(np.int64)
    lo = np.maximum(lo, 0)
    hi = np.minimum(hi, [width - 1, height - 1])
    span = hi - lo + 1
    keep = np.all(span > 0, axis=1)
    tri, lo, span = tri[keep], lo[keep], span[keep]
    sizes = span[:, 0] * span[:, 1]
    start = 0
    while start < len(tri):  # batches of triangles with a bounded number of candidate centres
        stop = start + max(1, int(np.searchsorted(np.cumsum(sizes[start:]), _CANDIDATES)))
        _fill(out, tri[start:stop], lo[start:stop], span[start:stop], sizes[start:stop])
        start = stop
    return out


def _fill(out, tri, lo, span, sizes) -> None:
    """Set the centres inside ``tri`` (T, 3, 2) among each triangle's bounding-box
    centres (``lo`` (T, 2), ``span`` (T, 2), ``sizes`` (T,) = span product)."""
    owner = np.repeat(np.arange(len(tri)), sizes)
    offset = np.arange(len(owner)) - np.repeat(np.cumsum(sizes) - sizes, sizes)
    px = lo[owner, 0] + offset % span[owner, 0]
    py = lo[owner, 1] + offset // span[owner, 0]
    a, b, c = tri[owner, 0], tri[owner, 1], tri[owner, 2]
    p = np.stack([px, py], axis=1).astype(np.float64)
    e0 = _cross(b - a, p - a)
    e1 = _cross(c - b, p - b)
    e2 = _cross(a - c, p - c)
    inside = ((e0 >= 0) & (e1 >= 0) & (e2 >= 0)) | ((e0 <= 0) & (e1 <= 0) & (e2 <= 0))
    inside &= _cross(b - a, c - a) != 0  # a degenerate triangle covers nothing
    out[py[inside], px[inside]] = True


def _cross(u, v) -> np.ndarray:
    return u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]


def object_coords(depth, mask, K, R, t) -> np.ndarray:
    """(H, W, 3) float64 object-frame coordinates (metres) of the surface each pixel of
    ``mask`` (H, W) bool sees, back-projected from ``depth`` (H, W) metres along the
    camera's z axis through ``K`` (3, 3, OpenCV centres) and the pose ``R``, ``t``
    (object to camera); 0 outside ``mask``."""
    h, w = np.shape(depth)
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    rays = np.stack([u, v, np.ones_like(u)], axis=-1) @ np.linalg.inv(np.asarray(K, dtype=np.float64)).T
    cam = rays * np.asarray(depth, dtype=np.float64)[..., None]
    obj = (cam - np.asarray(t, dtype=np.float64)) @ np.asarray(R, dtype=np.float64)  # R^T (X - t), row-wise
    return np.where(np.asarray(mask, dtype=bool)[..., None], obj, 0.0)

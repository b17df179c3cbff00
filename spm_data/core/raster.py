"""Silhouettes in numpy: which pixels a posed mesh covers, by one set of rules.

The distractor placement (spm_data.core.distractors) needs a target's and a
distractor's silhouettes many times a frame, before anything is rendered and
the same for every renderer, so it rasterises here rather than in OpenGL or
Blender; a cluttered frame's amodal mask is the target's silhouette. The rules
are those of bop_toolkit's vispy renderer on Mesa's llvmpipe (:func:`render_depth`:
vispy's matrices, the vertex shader in float32, draw's clipping at the frustum's
planes, 1/256-pixel vertex snapping and llvmpipe's fill rule), which a BOP export
draws its ground truth by (spm_data.formats.bop.gt), so a cluttered frame's mask
is its export's ``mask/`` to the pixel. pyrender on llvmpipe rasterises by the
same rules with its own float32 matrices, Blender samples pixel centres: their
masks match a silhouette up to an edge pixel or two (tests/core/test_raster.py).
"""

from __future__ import annotations

import numpy as np

from spm_data.core.poses import K_to_corner_origin
from spm_data.errors import SpmError

NEAR = 1e-3          # metres: a vertex closer to the camera plane than this is not projected
CLIP_NEAR, CLIP_FAR = 0.01, 100.0  # metres: both renderers' clipping planes; placement keeps distractors beyond
_CANDIDATES = 1 << 21  # pixel-centre tests per batch of triangles (memory bound)
MM_PER_M = 1000.0
_F = np.float32
_SUB = 256             # llvmpipe's subpixel steps per pixel (FIXED_ORDER 8)
_DEPTH_MAX = 1.0 - 0.5 / (2 ** 24 - 1)   # this deep, a fragment rounds to the cleared 24-bit depth: not drawn
_FLAT_MM = 1.0         # near and far planes at least this far apart (mm), the model between them


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
    """(height, width) bool: the pixels the mesh ``vertices`` (N, 3) metres, ``faces`` (F, 3)
    int covers, posed by ``R``, ``t`` (object to camera, OpenCV) and seen through ``K`` (3, 3,
    OpenCV pixel centres): render_depth's coverage of the mesh in mm as a BOP export's PLY holds
    it (float32), so a cluttered frame's amodal mask is the export's ``mask/`` to the pixel. Both
    faces of every triangle count. Triangles with a vertex behind ``NEAR`` are an error
    (placement keeps every object in front of the camera)."""
    _, z = project(vertices, K, R, t)
    if np.any(z[np.asarray(faces, dtype=np.int64)] < NEAR):
        raise SpmError("silhouette: a triangle reaches behind the camera; keep the mesh in front of it")
    vertices_mm = np.asarray(np.asarray(vertices, dtype=np.float64) * MM_PER_M, dtype=_F)
    t_mm = np.asarray(t, dtype=np.float64) * MM_PER_M
    return render_depth(vertices_mm, faces, K_to_corner_origin(K), np.asarray(R, dtype=np.float64), t_mm,
                        width, height) > 0


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


# --------------------------------------------------------------------------- the renderer's rules

def _matrices(vertices_mm, K, R, t_mm, width, height):
    """(mvp (4, 4) float32 as the shader gets it, near, far) as vispy's renderer computes them."""
    view_cv = np.eye(4, dtype=_F)
    view_cv[:3, :3], view_cv[:3, 3] = R, np.ravel(t_mm)
    flip = np.diag(np.array([1, -1, -1, 1], dtype=_F))   # OpenCV to OpenGL camera
    view = flip.dot(view_cv).T
    pts = np.asarray(vertices_mm, dtype=np.float64)
    lo, size = pts.min(axis=0), pts.max(axis=0) - pts.min(axis=0)
    corners = lo + np.array([[i >> 2 & 1, i >> 1 & 1, i & 1] for i in range(8)]) * size  # bbox corners: near, far
    z = view_cv[2, :].reshape((1, 4)).dot(np.concatenate((corners, np.ones((8, 1))), axis=1).T)
    near, far = z.min(), z.max()
    if far - near < _FLAT_MM:   # a flat model facing the camera: vispy's planes meet (it divides by 0 or
        near, far = (near + far) / 2 - _FLAT_MM / 2, (near + far) / 2 + _FLAT_MM / 2   # loses z): set apart
    q, qn = -(far + near) / float(far - near), -2 * (far * near) / float(far - near)
    proj = np.array([[2 * K[0, 0] / width, -0.0, (-2 * K[0, 2] + width) / width, 0],   # -0.0: vispy's K has no skew
                     [0, 2 * K[1, 1] / height, (2 * K[1, 2] - height) / height, 0], [0, 0, q, qn], [0, 0, -1, 0]])
    return np.dot(np.dot(np.eye(4, dtype=_F), view), proj.T).astype(_F), near, far


def _window_c(clip, width, height):
    """Window (x, y, z) float32 of new vertices (N, 4) as draw's clipper computes them (C, unfused)."""
    oow = _F(1.0) / clip[:, 3]
    scale = np.array([width / 2, height / 2, 0.5], dtype=_F)
    return (clip[:, :3] * oow[:, None]) * scale + scale


def _clip(clip, win, masks, width, height):
    """(T', 3, 3) float32 window coordinates of the triangles draw's clipper emits for triangles
    ``clip`` (T, 3, 4), ``win`` (T, 3, 3) crossing the frustum planes ``masks`` (T,) (bit p:
    plane p: x <= w, x >= -w, y <= w, y >= -w, z >= -w, z <= w), clipped plane by plane."""
    n_max = 3 + 6
    P, Q = np.zeros((len(clip), n_max, 4), _F), np.zeros((len(clip), n_max, 3), _F)
    P[:, :3], Q[:, :3], n = clip, win, np.full(len(clip), 3)
    sign = np.array([-1, 1, -1, 1, 1, -1], dtype=_F)
    for plane in range(6):
        act = np.flatnonzero((masks >> plane & 1).astype(bool) & (n >= 3))
        if not len(act):
            continue
        p, q, m = P[act], Q[act], n[act]
        dp = p[:, :, 3] + sign[plane] * p[:, :, plane // 2]      # one rounding, as draw's dot4 with 0/1 weights
        op, oq, cnt, rows = np.zeros_like(p), np.zeros_like(q), np.zeros(len(act), dtype=np.int64), np.arange(len(act))
        for i in range(1, n_max):
            live = i <= m
            cur, prv = np.where(i < m, i, 0), i - 1
            d0, d1 = dp[rows, prv], dp[rows, cur]
            keep = live & (d0 >= 0)
            op[rows[keep], cnt[keep]], oq[rows[keep], cnt[keep]] = p[keep, prv], q[keep, prv]
            cnt += keep
            cross = live & np.where(d0 >= 0, d1 < 0, ~(d1 < 0))
            if not cross.any():
                continue
            r = rows[cross]
            d0, d1, a, b = d0[cross], d1[cross], p[r, prv], p[r, cur[r]]
            denom = d1 - d0
            # draw interpolates from the vertex nearer the plane, with its own t
            from_cur = np.where(d1 < 0, -d1 < d0, ~(-d0 < d1))
            t = np.where(from_cur, d1 / denom, -d0 / denom).astype(_F)
            out, inn = np.where(from_cur[:, None], b, a), np.where(from_cur[:, None], a, b)
            new = out + t[:, None] * (inn - out)
            op[r, cnt[r]], oq[r, cnt[r]] = new, _window_c(new, width, height)
            cnt[r] += 1
        P[act], Q[act], n[act] = op, oq, cnt
    fans = [np.stack([Q[k, i - 1], Q[k, i], Q[k, 0]]) for k in range(len(Q)) for i in range(2, n[k])]
    return np.array(fans, dtype=_F).reshape(-1, 3, 3)


def render_depth(vertices_mm, faces, K, R, t_mm, width: int, height: int, offset=(0, 0)) -> np.ndarray:
    """(height, width) float32 depth (mm, 0 where nothing) of the model ``vertices_mm`` (V, 3),
    ``faces`` (F, 3) at ``R`` (3, 3), ``t_mm`` (3,) through ``K`` (3, 3, BOP's convention) with
    ``offset`` (dx, dy) pixels added to its principal point: bop_toolkit's vispy renderer's
    depth image on llvmpipe (the module's docstring)."""
    Kc = np.array(K, dtype=np.float64)
    Kc[:2, 2] += offset
    mvp, near, far = _matrices(vertices_mm, Kc, R, t_mm, width, height)
    v = np.asarray(vertices_mm, dtype=_F)
    clip = ((v[:, 0:1] * mvp[0] + v[:, 1:2] * mvp[1]) + v[:, 2:3] * mvp[2]) + mvp[3]   # the shader's order
    a = clip[:, :3] * (_F(1.0) / clip[:, 3])[:, None]
    scale = np.array([width / 2, height / 2, 0.5])
    win = (a.astype(np.float64) * scale + scale).astype(_F)   # one rounding: LLVM fuses the multiply-add
    x, y, z, w = clip.T
    bits = ((x > w) * 1 | (x + w < 0) * 2 | (y > w) * 4 | (y + w < 0) * 8 | (z + w < 0) * 16 | (z > w) * 32)
    fb = bits[np.asarray(faces)]
    crossing, out = fb[:, 0] | fb[:, 1] | fb[:, 2], fb[:, 0] & fb[:, 1] & fb[:, 2]
    tris = win[np.asarray(faces)[crossing == 0]]
    cut = np.flatnonzero((crossing != 0) & (out == 0))
    if len(cut):
        f = np.asarray(faces)[cut]
        tris = np.concatenate([tris, _clip(clip[f], win[f], crossing[cut], width, height)])
    pixel, zw = _fragments(tris, width, height)
    zbuf = np.full(width * height, np.inf)
    np.minimum.at(zbuf, pixel, zw)
    drawn = zbuf < _DEPTH_MAX
    depth = np.zeros(width * height, dtype=_F)
    depth[drawn] = ((near * far) / (near - far)) / (zbuf[drawn] + far / (near - far))
    return depth.reshape(height, width)[::-1]   # window rows count up from the bottom


def _fragments(tris, width, height):
    """(pixel index (N,), window depth (N,)) of the pixel centres the triangles ``tris`` (T, 3, 3)
    float32 window coordinates cover, by llvmpipe's rules: vertices snapped to 1/256 pixel
    (round to nearest even), an edge's pixels kept when strictly inside, or on it for the edges
    the fill convention keeps (top-left, in llvmpipe's y-up frame for framebuffer objects)."""
    fixed = np.rint((tris[:, :, :2] - _F(0.5)).astype(_F) * _F(_SUB)).astype(np.int64)
    X, Y = fixed[:, :, 0], fixed[:, :, 1]
    area = (X[:, 0] - X[:, 1]) * (Y[:, 2] - Y[:, 0]) - (X[:, 2] - X[:, 0]) * (Y[:, 0] - Y[:, 1])
    keep = area != 0
    X, Y, tris, flip = X[keep], Y[keep], tris[keep].astype(np.float64), area[keep] < 0
    X[flip], Y[flip] = X[flip][:, [1, 0, 2]], Y[flip][:, [1, 0, 2]]   # counter-clockwise, as llvmpipe turns them
    dcdx, dcdy = Y - np.roll(Y, -1, axis=1), X - np.roll(X, -1, axis=1)
    bias = ((dcdx < 0) | ((dcdx == 0) & (dcdy > 0))).astype(np.int64)
    lo = np.maximum(-(-np.stack([X.min(1), Y.min(1)], 1) // _SUB), 0)
    hi = np.minimum(np.stack([X.max(1), Y.max(1)], 1) // _SUB, [width - 1, height - 1])
    span = np.maximum(hi - lo + 1, 0)
    sizes = span[:, 0] * span[:, 1]
    pixels, depths, start = [], [], 0
    while start < len(X):
        stop = start + max(1, int(np.searchsorted(np.cumsum(sizes[start:]), _CANDIDATES)))
        s = slice(start, stop)
        owner = np.repeat(np.arange(start, stop), sizes[s])
        offset = np.arange(len(owner)) - np.repeat(np.cumsum(sizes[s]) - sizes[s], sizes[s])
        px = lo[owner, 0] + offset % np.maximum(span[owner, 0], 1)
        py = lo[owner, 1] + offset // np.maximum(span[owner, 0], 1)
        inside = np.ones(len(owner), dtype=bool)
        for e in range(3):
            value = dcdx[owner, e] * (X[owner, e] - px * _SUB) - dcdy[owner, e] * (Y[owner, e] - py * _SUB)
            inside &= value + bias[owner, e] > 0
        owner, px, py = owner[inside], px[inside], py[inside]
        pixels.append(py * width + px)
        depths.append(_plane_z(tris[owner], px + 0.5, py + 0.5))
        start = stop
    return (np.concatenate(pixels), np.concatenate(depths)) if pixels else (np.zeros(0, int), np.zeros(0))


def _plane_z(tri, x, y):
    """Window depth at (x, y) on the plane through each triangle ``tri`` (N, 3, 3) float64."""
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    det = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
    dx, dy = x - tri[:, 0, 0], y - tri[:, 0, 1]
    b1, b2 = (dx * e2[:, 1] - dy * e2[:, 0]) / det, (e1[:, 0] * dy - e1[:, 1] * dx) / det
    return tri[:, 0, 2] + b1 * e1[:, 2] + b2 * e2[:, 2]

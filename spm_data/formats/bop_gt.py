"""BOP ground truth per object and frame, as bop_toolkit's scripts compute it from the export.

``scripts/calc_gt_info.py`` renders each object alone (vispy, on Mesa's llvmpipe) on a
canvas three times the image's size, the image in its middle, turns depths into distances
along the rays, and calls a pixel visible where the object is at most 15 mm behind the
scene's depth PNG or the PNG has no depth ("bop19"); ``scripts/calc_gt_masks.py`` does the
same at the image's size for ``mask/`` and ``mask_visib/``. :func:`object_gt` computes both
by those rules from what the export writes (model PLY, ``cam_K``, pose, depth PNG), with
:func:`render_depth` drawing a model as that renderer does: vispy's matrices (near and far
planes at the model's bounding box), the vertex shader in float32, draw's clipping at the
frustum's planes (no guard band), 1/256-pixel vertex snapping and the fill rule of
llvmpipe's rasteriser, so that the counts, boxes and masks agree to the pixel, also for
objects cut by the image border. (A GPU driver snaps and clips its own way: there an
edge pixel or two may go the other way.)

Depth PNGs (:func:`depth_scale_for`): uint16 × ``depth_scale`` = mm; the scale is chosen
per image so the farthest depth fits (BOP stores it per image).
"""

from __future__ import annotations

import numpy as np

from spm_data.errors import SpmError

# mm per depth unit: the finest of these whose range (65535 units) holds the image's farthest
# depth. 0.1 mm (BOP's usual choice) reaches 6.5535 m; 10 mm reaches 655 m.
DEPTH_SCALES = (0.1, 0.2, 0.5, 1.0, 2.0, 5.0, 10.0)
# An occluder's depth, as a fraction of the object's nearest point: far enough in front (20 %,
# 100 mm at 0.5 m) that bop_toolkit's visibility test (15 mm tolerance) sees the object hidden.
OCCLUDER_DEPTH = 0.8
NO_BOX = [-1, -1, -1, -1]
DELTA_MM = 15.0          # calc_gt_info's and calc_gt_masks' visibility tolerance
_F = np.float32
_SUB = 256               # llvmpipe's subpixel steps per pixel (FIXED_ORDER 8)
_DEPTH_MAX = 1.0 - 0.5 / (2 ** 24 - 1)   # this deep, a fragment rounds to the cleared 24-bit depth: not drawn
_CANDIDATES = 1 << 21    # pixel-centre tests per batch of triangles (memory bound)


def depth_scale_for(depth_m: np.ndarray) -> float:
    """The finest of DEPTH_SCALES (mm per unit) whose 65535 units hold the largest of ``depth_m``
    (metres, any shape); SpmError (one line) when even the coarsest does not."""
    far_mm = float(np.max(depth_m, initial=0.0)) * 1000.0
    for scale in DEPTH_SCALES:
        if round(far_mm / scale) <= 65535:
            return scale
    raise SpmError(f"a depth of {far_mm / 1000:.1f} m does not fit a BOP depth PNG even at "
                   f"{DEPTH_SCALES[-1]:g} mm per unit (at most {65535 * DEPTH_SCALES[-1] / 1000:.0f} m); "
                   "render the objects nearer")


def depth_units(depth_m: np.ndarray, scale: float) -> np.ndarray:
    """(H, W) uint16 PNG values for ``depth_m`` (H, W) metres at ``scale`` mm per unit
    (from depth_scale_for, so nothing is clipped)."""
    units = np.round(np.asarray(depth_m, dtype=np.float64) * 1000.0 / scale)
    return units.astype(np.uint16)


def bbox(mask: np.ndarray, offset=(0, 0)) -> list[int]:
    """[x, y, w, h] of ``mask``'s pixels as calc_gt_info writes it: w = x_max - x_min (no + 1;
    COCO's boxes add 1), minus ``offset`` (x, y) pixels; NO_BOX when empty."""
    ys, xs = np.nonzero(mask)
    if len(ys) == 0:
        return list(NO_BOX)
    return [int(xs.min() - offset[0]), int(ys.min() - offset[1]), int(xs.max() - xs.min()), int(ys.max() - ys.min())]


def depth_with_occluders(depth: np.ndarray, mask: np.ndarray, visible: np.ndarray) -> np.ndarray:
    """Depth (H, W) metres where our 2-D occluders hide the object: there, a flat occluder at
    OCCLUDER_DEPTH of the object's nearest depth. BOP's tools (calc_gt_info, VSD) find what is
    visible from depth, so without it they would call every occluded object fully visible."""
    hidden = mask & ~visible
    if not hidden.any() or not (mask & (depth > 0)).any():
        return depth
    out = depth.copy()
    stand_in = OCCLUDER_DEPTH * depth[mask & (depth > 0)].min()
    # Nearer things already in the depth (a 3-D distractor over a rectangle) stay in front.
    out[hidden] = np.where(depth[hidden] > 0, np.minimum(depth[hidden], stand_in), stand_in)
    return out


# --------------------------------------------------------------------------- calc_gt_info's and calc_gt_masks' rules

def distances(depth_mm: np.ndarray, K) -> np.ndarray:
    """(H, W) float64 mm from the camera centre, of ``depth_mm`` (H, W) along z, through ``K``
    (3, 3, BOP's convention), by bop_toolkit's formula (misc.depth_im_to_dist_im_fast)."""
    h, w = depth_mm.shape
    xs, ys = np.meshgrid(np.arange(w), np.arange(h))
    px, py = (xs - K[0, 2]) / np.float64(K[0, 0]), (ys - K[1, 2]) / np.float64(K[1, 1])
    return np.sqrt(np.multiply(px, depth_mm) ** 2 + np.multiply(py, depth_mm) ** 2 + depth_mm.astype(np.float64) ** 2)


def visible_mask(dist_scene: np.ndarray, dist_model: np.ndarray, delta: float = DELTA_MM) -> np.ndarray:
    """(H, W) bool, bop19 visibility: the model's distance at most ``delta`` mm behind the scene's,
    or the scene without depth, where the model is (differences in float32, as bop_toolkit's)."""
    diff = dist_model.astype(_F) - dist_scene.astype(_F)
    return ((diff <= delta) | (dist_scene == 0)) & (dist_model > 0)


def png_depth_mm(units: np.ndarray, scale: float) -> np.ndarray:
    """(H, W) float32 mm of a depth PNG's ``units`` at ``scale`` mm per unit, as inout.load_depth
    and the scripts read it (float32 times the scale)."""
    return units.astype(_F) * scale


def object_gt(vertices_mm, faces, K, R, t_mm, scene_depth_mm) -> tuple[dict, np.ndarray, np.ndarray]:
    """One object's (scene_gt_info entry, mask (H, W) bool, mask_visib (H, W) bool), as
    calc_gt_info and calc_gt_masks compute them: the model (``vertices_mm`` (V, 3) float32 as its
    PLY stores them, ``faces`` (F, 3)) at ``R`` (3, 3), ``t_mm`` (3,) through ``K`` (3, 3, BOP's
    convention), seen against the scene's ``scene_depth_mm`` (H, W, png_depth_mm)."""
    h, w = scene_depth_mm.shape
    large = render_depth(vertices_mm, faces, K, R, t_mm, 3 * w, 3 * h, offset=(w, h))
    dist_scene = distances(scene_depth_mm, K)
    dist_gt = distances(large[h:2 * h, w:2 * w], K)
    visib = visible_mask(dist_scene, dist_gt)
    full, seen = large > 0, int(visib.sum())
    info = {"bbox_obj": bbox(full, offset=(w, h)) if seen else list(NO_BOX),
            "bbox_visib": bbox(visib), "px_count_all": int(full.sum()),
            "px_count_valid": int((dist_scene[dist_gt > 0] > 0).sum()), "px_count_visib": seen,
            "visib_fract": seen / float(full.sum()) if full.any() else 0.0}
    dist_small = distances(render_depth(vertices_mm, faces, K, R, t_mm, w, h), K)
    return info, dist_small > 0, visible_mask(dist_scene, dist_small)


def image_gt(mask: np.ndarray, visible: np.ndarray, depth: np.ndarray) -> dict:
    """The scene_gt_info entry of an object without a model (an imported frame): its ``mask``
    (H, W) bool inside the image is all there is of it; ``visible`` (H, W) bool, ``depth``
    (H, W) metres the exported depth."""
    full, vis = int(mask.sum()), int(visible.sum())
    return {"bbox_obj": bbox(mask) if vis else list(NO_BOX), "bbox_visib": bbox(visible), "px_count_all": full,
            "px_count_valid": int((depth[mask] > 0).sum()), "px_count_visib": vis,
            "visib_fract": vis / full if full else 0.0}


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

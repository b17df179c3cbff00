"""N3M, offline stage 1: feature points on the training views, lifted to 3-D object
coordinates, merged across views, and scored (repeatability, distinctiveness).

Frames and units: pixels are OpenCV centres of the image as given (not of an upsampled
copy); 3-D points are metres in the object frame (x_cam = R @ x_obj + t,
spm_data/core/poses.py); descriptors are OpenCV SIFT (128 float32).
"""

from __future__ import annotations

import cv2
import numpy as np
from scipy.spatial import cKDTree

from spm_model.base.feature_memo import memoized

DEPTH_STEP = 0.02     # a keypoint whose 3x3 depth neighbourhood spans more than this fraction
                      # of its depth sits on a silhouette or a grazing surface: not lifted
VISIBLE_SIDE = 64     # depth maps kept for the visibility test, at most this many pixels a side
VISIBLE_TOL = 0.05    # a point is visible in a view if its depth agrees within this fraction
TREE_SEED = 0         # FLANN draws its kd-trees from OpenCV's per-thread generator, whose state is
                      # whatever ran before in the process (another split, a RANSAC): seeded
                      # before every build, the index, and so N3M, is the same on any worker


def make_sift(max_keypoints: int):
    """One OpenCV SIFT detector keeping at most ``max_keypoints`` per image (0: all)."""
    return cv2.SIFT_create(nfeatures=int(max_keypoints))


def sift_features(rgb, mask, *, side: int, sift) -> tuple[np.ndarray, np.ndarray]:
    """SIFT inside ``mask``: ``rgb`` (H, W, 3) uint8, ``mask`` (H, W) bool. Images whose
    shorter side is below ``side`` pixels are upsampled (bicubic) to it first, never
    downsampled. Returns ``uv`` (n, 2) float64 pixels of the image as given and
    ``desc`` (n, 128) float32."""
    mask = np.asarray(mask, dtype=bool)
    h, w = mask.shape
    gray = cv2.cvtColor(np.ascontiguousarray(rgb, dtype=np.uint8), cv2.COLOR_RGB2GRAY)
    m = mask.astype(np.uint8) * 255
    f = max(1.0, float(side) / min(h, w))
    size = (int(round(w * f)), int(round(h * f)))
    if f > 1.0:
        gray = cv2.resize(gray, size, interpolation=cv2.INTER_CUBIC)
        m = cv2.resize(m, size, interpolation=cv2.INTER_NEAREST)
    keypoints, desc = sift.detectAndCompute(gray, m)
    if desc is None or not keypoints:
        return np.zeros((0, 2)), np.zeros((0, 128), np.float32)
    pts = np.array([kp.pt for kp in keypoints], dtype=np.float64)
    scale = np.array([size[0] / w, size[1] / h])
    return (pts + 0.5) / scale - 0.5, desc.astype(np.float32)


def remembered_sift_features(rgb, mask, *, side: int, max_keypoints: int, sift) -> tuple[np.ndarray, np.ndarray]:
    """sift_features of a ``make_sift(max_keypoints)`` detector, remembered per image
    (spm_model/base/feature_memo.py: a benchmark shows N3M each frame in several folds and
    runs). The key names no method: SIFT + PnP (sift_pnp.py) with the same ``side`` and
    ``max_keypoints`` is served what N3M extracted, and the other way round. Descriptors are kept as uint8 when exact
    (OpenCV's SIFT values are whole
    numbers 0..255) and returned float32 (n, 128), a new array each call."""
    def compute():
        uv, desc = sift_features(rgb, mask, side=side, sift=sift)
        small = desc.astype(np.uint8)
        return uv, small if np.array_equal(small, desc) else desc

    uv, desc = memoized(("n3m-sift", int(side), int(max_keypoints)), (rgb, mask), compute)
    return uv, desc.astype(np.float32)


def lift(uv, depth, K, R, t) -> tuple[np.ndarray, np.ndarray]:
    """Object-frame 3-D points of pixels ``uv`` (n, 2) from ``depth`` (H, W) metres
    (0 = nothing), ``K`` (3, 3), pose ``R``, ``t``. Returns ``xyz`` (n, 3) metres and
    ``ok`` (n,) bool: False off the object, on a silhouette or a grazing surface
    (DEPTH_STEP), where the depth at the pixel is not the surface the keypoint saw."""
    depth = np.asarray(depth, dtype=np.float32)
    h, w = depth.shape
    uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    col = np.clip(np.rint(uv[:, 0]).astype(int), 0, w - 1)
    row = np.clip(np.rint(uv[:, 1]).astype(int), 0, h - 1)
    kernel = np.ones((3, 3), np.uint8)
    hi = cv2.dilate(depth, kernel)[row, col]
    lo = cv2.erode(depth, kernel)[row, col]
    d = depth[row, col].astype(np.float64)
    ok = (lo > 0) & (hi - lo <= DEPTH_STEP * np.maximum(d, 1e-9))
    K = np.asarray(K, dtype=np.float64)
    y = (uv[:, 1] - K[1, 2]) / K[1, 1]                       # K^-1 [u, v, 1] of an upper-triangular K
    rays = np.column_stack([(uv[:, 0] - K[0, 2] - K[0, 1] * y) / K[0, 0], y, np.ones(len(uv))])
    xyz = (rays * d[:, None] - np.asarray(t, dtype=np.float64)) @ np.asarray(R, dtype=np.float64)
    return xyz, ok


def merge_observations(xyz, strength, radius: float) -> np.ndarray:
    """Observations of one object, ``xyz`` (n, 3) metres, grouped into 3-D points: the
    strongest unassigned observation (largest ``strength`` (n,)) takes every unassigned
    one within ``radius`` metres, and so on. Returns (n,) int point ids 0..p-1."""
    xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
    labels = np.full(len(xyz), -1, dtype=np.int64)
    if len(xyz) == 0:
        return labels
    near = cKDTree(xyz).query_ball_point(xyz, r=radius)
    count = 0
    for i in np.argsort(-np.asarray(strength, dtype=np.float64), kind="stable"):
        if labels[i] >= 0:
            continue
        members = np.asarray(near[i], dtype=np.int64)
        labels[members[labels[members] < 0]] = count
        count += 1
    return labels


def group_medians(values, starts) -> np.ndarray:
    """(g, d): per group of rows ``starts[i]:starts[i + 1]`` of ``values`` (n, d), what
    ``np.median(axis=0)`` gives for it, bit for bit (the middle value, or the mean of the two
    middle ones: (a + b) / 2), for every group at once."""
    values = np.asarray(values, dtype=np.float64)
    starts = np.asarray(starts, dtype=np.int64)
    lengths = np.diff(starts)
    group = np.repeat(np.arange(len(lengths)), lengths)
    low, high = starts[:-1] + (lengths - 1) // 2, starts[:-1] + lengths // 2
    out = np.empty((len(lengths), values.shape[1]))
    for c in range(values.shape[1]):
        ordered = values[np.lexsort((values[:, c], group)), c]
        out[:, c] = np.where(lengths % 2 == 1, ordered[low], (ordered[low] + ordered[high]) / 2)
    return out


def spread_picks(lengths, count: int) -> list:
    """Per length L of ``lengths``, the (distinct, increasing) positions of at most ``count`` items
    spread evenly over 0..L-1, first and last included: rint(linspace(0, L - 1, min(L, count)))."""
    known: dict = {}
    for length in map(int, np.unique(lengths)):
        known[length] = np.unique(np.rint(np.linspace(0, length - 1, min(length, count))).astype(int))
    return [known[int(length)] for length in lengths]


def small_depth(depth) -> np.ndarray:
    """``depth`` (H, W) downsampled (nearest) to at most VISIBLE_SIDE a side, float32."""
    depth = np.asarray(depth, dtype=np.float32)
    h, w = depth.shape
    f = min(1.0, VISIBLE_SIDE / max(h, w))
    if f >= 1.0:
        return depth.copy()
    return cv2.resize(depth, (max(1, int(round(w * f))), max(1, int(round(h * f)))),
                      interpolation=cv2.INTER_NEAREST)


def visibility(points, depths, shapes, Ks, Rs, ts) -> np.ndarray:
    """(p, v) bool: whether object point ``points[i]`` (p, 3) metres is seen in view j:
    it projects inside the image (H, W) ``shapes[j]`` through ``Ks[j]``, ``Rs[j]``,
    ``ts[j]``, and the view's small depth map (:func:`small_depth`) there agrees with
    its depth within VISIBLE_TOL (so it is on the object and not hidden)."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    out = np.zeros((len(points), len(depths)), dtype=bool)
    for j, (small, shape) in enumerate(zip(depths, shapes)):
        cam = points @ np.asarray(Rs[j]).T + np.asarray(ts[j])
        z = cam[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            uv = (cam @ np.asarray(Ks[j]).T)[:, :2] / z[:, None]
        sh, sw = small.shape
        col = np.floor((uv[:, 0] + 0.5) * sw / shape[1]).astype(np.int64, copy=False)
        row = np.floor((uv[:, 1] + 0.5) * sh / shape[0]).astype(np.int64, copy=False)
        inside = (z > 0) & (col >= 0) & (col < sw) & (row >= 0) & (row < sh)
        d = np.zeros(len(points))
        d[inside] = small[row[inside], col[inside]]
        out[:, j] = inside & (d > 0) & (np.abs(d - z) <= VISIBLE_TOL * np.abs(z))
    return out


def distinctiveness(desc, xyz, *, same_radius: float, ratio: float, checks: int = 32) -> np.ndarray:
    """Per stored descriptor ``desc`` (n, 128), whether it is told apart from every other
    3-D point: its nearest other descriptor at the same place (``xyz`` (n, 3) within
    ``same_radius`` metres: the same point, or its copy in another sequence) is nearer
    than ``ratio`` times the nearest one elsewhere. Returns (n,) float, 1 (distinct) or 0."""
    n = len(desc)
    if n < 2:
        return np.zeros(n)
    idx, dist = knn(build_index(desc), desc, min(n, 8), checks=checks)
    self_hit = idx == np.arange(n)[:, None]
    same = (np.linalg.norm(xyz[idx] - xyz[:, None, :], axis=2) <= same_radius) & ~self_hit
    other = ~same & ~self_hit
    inf = np.inf
    own = np.where(same, dist, inf).min(axis=1)
    rival = np.where(other, dist, inf).min(axis=1)
    return (np.isfinite(own) & (own < ratio * rival)).astype(np.float64)


def build_index(database):
    """A FLANN index (4 randomised kd-trees, drawn with TREE_SEED) over ``database`` (m, 128)
    float32 rows. Reseeds OpenCV's generator of the calling thread (cv2.setRNGSeed)."""
    cv2.setRNGSeed(TREE_SEED)
    return cv2.flann_Index(np.ascontiguousarray(database, dtype=np.float32), {"algorithm": 1, "trees": 4})


def knn(index, queries, k: int, *, checks: int = 32) -> tuple[np.ndarray, np.ndarray]:
    """The ``k`` nearest indexed rows (:func:`build_index`) of each query (n, 128):
    ``idx`` (n, k) int64 and ``dist`` (n, k) float64 Euclidean distances, nearest first
    (FLANN visits ``checks`` leaves: approximate)."""
    queries = np.ascontiguousarray(queries, dtype=np.float32)
    if len(queries) == 0:
        return np.zeros((0, k), np.int64), np.zeros((0, k))
    idx, d2 = index.knnSearch(queries, int(k), params={"checks": int(checks)})
    return idx.astype(np.int64), np.sqrt(np.maximum(d2.astype(np.float64), 0.0))

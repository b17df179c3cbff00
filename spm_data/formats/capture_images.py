"""Pictures of a real capture as they are imported (spm_data/formats/importing.py reads them):
lens undistortion, and the mask of a frame whose capture has none (``--mask``).

Masks (docs/datasets.md, "Masks when the capture has none"):

* ``none``: the whole frame is the object (methods that work on whole images see all of it).
* ``sphere``: the projection of a sphere of ``--radius`` around ``--center`` (the object
  frame's origin): the pixels whose ray meets the sphere; a region of interest.
* ``grabcut``: OpenCV's GrabCut seeded by that projection: probable foreground inside it,
  background outside; :data:`GRABCUT_ITERATIONS` rounds on the image scaled so that its longer
  side is at most :data:`GRABCUT_SIDE` pixels, the result scaled back (linear, cut at one half)
  and kept inside the sphere's projection.
"""

from __future__ import annotations

import numpy as np

from spm_data.errors import SpmError
from spm_data.io.images import ImageError

MASK_METHODS = ("none", "sphere", "grabcut")
GRABCUT_SIDE = 256        # pixels, the longer side GrabCut works at (its cost grows with the pixels)
GRABCUT_ITERATIONS = 3    # rounds of GrabCut (5, OpenCV's example, moved the test's median IoU by < 0.002)
GRABCUT_SEED = 0          # cv2.setRNGSeed before each call: its GMM initialisation is random


def undistort(image: np.ndarray, K: np.ndarray, distortion: tuple, fisheye: bool, nearest: bool) -> np.ndarray:
    """``image`` (H, W[, C]) seen through the lens ``distortion`` (OpenCV's coefficients, or its
    fisheye model's k1..k4) as the pinhole camera ``K`` (3, 3) would see it: OpenCV's undistortion
    map, sampled bilinearly (``nearest``: nearest neighbour, for masks and depth)."""
    import cv2

    h, w = image.shape[:2]
    dist = np.asarray(distortion, dtype=np.float64)
    if fisheye:
        maps = cv2.fisheye.initUndistortRectifyMap(K, dist, np.eye(3), K, (w, h), cv2.CV_32FC1)
    else:
        maps = cv2.initUndistortRectifyMap(K, dist, None, K, (w, h), cv2.CV_32FC1)
    flag = cv2.INTER_NEAREST if nearest else cv2.INTER_LINEAR
    return cv2.remap(image, maps[0], maps[1], flag, borderMode=cv2.BORDER_CONSTANT, borderValue=0)


def lens_coverage(K, distortion: tuple, fisheye: bool, width: int, height: int) -> float:
    """The fraction of the undistorted image (K, ``width`` x ``height``) that :func:`undistort`
    fills from inside the photo (a 16 x 16 grid of its pixels); 1.0 without distortion. A lens whose
    coefficients are absurd (k1 = 1e10) fills almost nothing: every mask would be empty."""
    if not any(distortion):
        return 1.0
    import cv2

    K = np.asarray(K, dtype=np.float64).reshape(3, 3)
    u, v = np.meshgrid(np.linspace(0, width - 1, 16), np.linspace(0, height - 1, 16))
    rays = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], -1).reshape(1, -1, 3)
    dist = np.asarray(distortion, dtype=np.float64)
    with np.errstate(all="ignore"):
        if fisheye:
            uv = cv2.fisheye.projectPoints(rays, np.zeros(3), np.zeros(3), K, dist)[0]
        else:
            uv = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), K, dist)[0]
        uv = uv.reshape(-1, 2)
        inside = np.isfinite(uv).all(axis=1) & (uv[:, 0] >= -0.5) & (uv[:, 0] <= width - 0.5) \
            & (uv[:, 1] >= -0.5) & (uv[:, 1] <= height - 0.5)
    return float(inside.mean())


def sphere_mask(K, t, radius_m: float, width: int, height: int) -> np.ndarray:
    """(height, width) uint8: 1 where the pixel's ray (OpenCV K (3, 3)) meets the sphere of
    ``radius_m`` metres around the object origin, which sits at ``t`` (3,) in the camera frame;
    every pixel when the camera is inside the sphere, none when the sphere is behind it."""
    K = np.asarray(K, dtype=np.float64).reshape(3, 3)
    centre = np.asarray(t, dtype=np.float64).reshape(3)
    distance = float(np.linalg.norm(centre))
    if distance <= radius_m:
        return np.ones((height, width), np.uint8)
    # A ray meets the sphere where its angle to the centre is at most asin(radius / distance).
    cos_limit = np.sqrt(1.0 - (radius_m / distance) ** 2)
    Kinv = np.linalg.inv(K).astype(np.float32)
    u = np.arange(width, dtype=np.float32)[None, :]
    v = np.arange(height, dtype=np.float32)[:, None]
    rays = [Kinv[i, 0] * u + Kinv[i, 1] * v + Kinv[i, 2] for i in range(3)]
    dot = sum(r * np.float32(c) for r, c in zip(rays, centre / distance))
    norm = np.sqrt(rays[0] ** 2 + rays[1] ** 2 + rays[2] ** 2)
    return (dot >= cos_limit * norm).astype(np.uint8)


def grabcut_mask(rgb: np.ndarray, seed: np.ndarray) -> np.ndarray:
    """(H, W) uint8 mask of the object in ``rgb`` (H, W, 3) uint8 by GrabCut, seeded by ``seed``
    (H, W): probable foreground where it is set, background elsewhere (the frame's border is
    probable background where the seed covers everything). Parameters: the module's docstring."""
    import cv2

    h, w = seed.shape
    if not seed.any():
        return seed.astype(np.uint8)
    scale = min(1.0, GRABCUT_SIDE / max(h, w))
    size = (max(1, round(w * scale)), max(1, round(h * scale)))
    small = cv2.resize(rgb, size, interpolation=cv2.INTER_AREA) if scale < 1 else np.ascontiguousarray(rgb)
    labels = np.where(cv2.resize(seed.astype(np.uint8), size, interpolation=cv2.INTER_NEAREST) > 0,
                      cv2.GC_PR_FGD, cv2.GC_BGD).astype(np.uint8)
    if not (labels == cv2.GC_BGD).any():
        labels[[0, -1], :] = labels[:, [0, -1]] = cv2.GC_PR_BGD
    cv2.setRNGSeed(GRABCUT_SEED)
    try:
        cv2.grabCut(small, labels, None, np.zeros((1, 65)), np.zeros((1, 65)), GRABCUT_ITERATIONS,
                    cv2.GC_INIT_WITH_MASK)
    except cv2.error as exc:
        raise ImageError(f"GrabCut found no object ({str(exc).strip().splitlines()[-1]})") from None
    found = ((labels == cv2.GC_FGD) | (labels == cv2.GC_PR_FGD)).astype(np.uint8) * 255
    if scale < 1:
        found = cv2.resize(found, (w, h), interpolation=cv2.INTER_LINEAR)
    return ((found >= 128) & (seed > 0)).astype(np.uint8)


def capture_mask(method: str, rgb: np.ndarray, K, t, radius_m: float) -> np.ndarray:
    """(H, W) uint8 mask of a frame by ``method`` (MASK_METHODS) from its undistorted ``rgb``,
    OpenCV ``K`` and the object origin's place ``t`` in the camera frame."""
    h, w = rgb.shape[:2]
    if method == "none":
        return np.ones((h, w), np.uint8)
    seed = sphere_mask(K, t, radius_m, w, h)
    return seed if method == "sphere" else grabcut_mask(rgb, seed)


def mask_source(method: str | None, radius) -> str:
    """What a shard's ``mask_source`` attribute says of masks made by ``method`` (None: the capture's
    own files); ``radius`` in the data's units, as given."""
    if method is None:
        return "mask_path, --mask-dir, or alpha >= 128"
    if method == "none":
        return "none: the whole frame"
    sphere = f"the projection of a sphere of radius {radius:g} (the data's units) around the object origin"
    if method == "sphere":
        return f"sphere: {sphere}"
    return (f"grabcut: OpenCV GrabCut seeded by {sphere} (probable foreground inside, background outside; "
            f"{GRABCUT_ITERATIONS} iterations at <= {GRABCUT_SIDE} px, RNG seed {GRABCUT_SEED})")


def made_masks(method, radius, metres_per_unit: float, unit: str, origin: str = "the object origin") -> tuple:
    """(method, sphere radius in metres) of ``--mask``/``--radius`` (``radius`` in ``unit``, metres per
    unit ``metres_per_unit``, around ``origin``); () without --mask; SpmError for options that do not fit."""
    if method is None:
        if radius is not None:
            raise SpmError("--radius is the sphere of --mask sphere or --mask grabcut; give one of them too")
        return ()
    if method not in MASK_METHODS:
        raise SpmError(f"--mask takes one of {', '.join(MASK_METHODS)}, got {method!r}")
    if method == "none":
        return ("none", 0.0)
    if radius is None or not 0 < radius < float("inf"):
        raise SpmError(f"--mask {method} needs --radius R: the object's radius around {origin}, in {unit} (a finite "
                       f"number > 0){'' if radius is None else f', got {radius}'}")
    return (method, float(radius) * metres_per_unit)

"""Per-frame SPM features (keypoints -> bunches -> ellipse -> 16-d manifold vector)
and raw image vectors for the baselines. Pure numpy + OpenCV; no renderer.

Two feature vectors per frame, by the keypoint rule of docs/method.md:
- ``train``: keypoints that are RANSAC-homography inliers against the frame's
  5-degree path neighbours (the previous and the next view of the same
  instance in the same shard; a keypoint kept by either counts). A frame with
  no path neighbour in its shard (``spm-data render --limit`` spreads frames
  over views; imported folders may hold single views) falls back to the query
  rule, and ``train_neighbours`` (0) records that it did;
- ``query``: every keypoint inside the object mask, as for a single image.
A frame with fewer than 2 * gamma usable keypoints gets NaN and is counted.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass

import numpy as np

from spm_model.errors import FeatureError
from spm_model.base.images import raw_vector
from spm_model.spm.bunches import BunchError, fit_bunches
from spm_model.spm.ellipse import EllipseError
from spm_model.spm.keypoints import sift_locations
from spm_model.spm.manifold import ORDERS, initial_manifold

# 5: template descriptors and K in the cache; 6: from the visible mask; 7: small images upsampled
# (min_side) and which frames have depth (has_depth) in the cache; 8: the cache file sealed (its arrays,
# shard and configuration under one SHA-256: a damaged file is extracted again, never read).
FEATURE_VERSION = 8


@dataclass(frozen=True)
class FeatureConfig:
    """gamma: EM clusters; ellipse: "pso" (Eq. 1) or "direct"; lam: Eq. 1's lambda;
    max_side: images whose longest side exceeds it are downscaled before SIFT (the
    manifold vector is scale invariant); min_side: images whose shorter side is below it are
    upsampled (bicubic) to it before SIFT, which finds few keypoints on small images (a 32-pixel
    COIL view); raw_size: side of the baselines' raw vectors.
    Opt-in variants of the manifold vector (spm_model/spm/manifold.py; the defaults are
    the pipeline of docs/method.md): order: cluster order, "sign" (canonical_order's
    rule), "angle" or "distance"; normalise: scale the vector to unit length;
    append_ellipse: append the ellipse's axis ratio and orientation (3 values)."""

    gamma: int = 8
    ellipse: str = "pso"
    lam: float = 0.1
    seed: int = 0
    max_side: int = 256
    min_side: int = 128
    raw_size: int = 32
    order: str = "sign"
    normalise: bool = True
    append_ellipse: bool = False

    def __post_init__(self):
        if self.gamma < 5:
            raise FeatureError(f"gamma must be >= 5 (an ellipse needs 5 centres), got {self.gamma}")
        if self.ellipse not in ("pso", "direct"):
            raise FeatureError(f"ellipse must be 'pso' or 'direct', got {self.ellipse!r}")
        if self.order not in ORDERS:
            raise FeatureError(f"order must be one of {ORDERS}, got {self.order!r}")
        if not 0 < self.min_side <= self.max_side:
            raise FeatureError(f"min_side must be in 1..max_side ({self.max_side}), got {self.min_side}")

    @property
    def dims(self) -> int:
        return 2 * self.gamma + (3 if self.append_ellipse else 0)

    def key(self) -> str:
        """Short hash naming the cache files made with this configuration."""
        text = json.dumps({**asdict(self), "version": FEATURE_VERSION}, sort_keys=True)
        return hashlib.sha256(text.encode()).hexdigest()[:12]


def working_image(rgb: np.ndarray, mask: np.ndarray | None, max_side: int, min_side: int = 1):
    """(H, W, 3) uint8 RGB and its (H, W) mask as SIFT sees them: downscaled (area) so the
    longest side is <= max_side, or upsampled (bicubic) so the shorter side is >= min_side
    (but the longest no more than max_side); as given when both hold."""
    import cv2

    h, w = rgb.shape[:2]
    scale = max_side / max(h, w)
    if scale >= 1:  # upsampled, never past max_side
        scale = min(scale, max(1.0, min_side / min(h, w)))
        if scale == 1.0:
            return rgb, mask
    size = (max(1, round(w * scale)), max(1, round(h * scale)))
    small = cv2.resize(np.ascontiguousarray(rgb), size,
                       interpolation=cv2.INTER_AREA if scale < 1 else cv2.INTER_CUBIC)
    if mask is not None:
        mask = cv2.resize((np.asarray(mask) > 0).astype(np.uint8), size, interpolation=cv2.INTER_NEAREST)
    return small, mask


def manifold_from_keypoints(locations: np.ndarray, config: FeatureConfig) -> tuple[np.ndarray, float]:
    """(N, 2) keypoint pixels -> ((config.dims,) manifold vector, eccentricity); by
    default a (2 * gamma,) unit vector. Raises FeatureError when N < 2 * gamma or
    no ellipse fits."""
    try:
        bunches = fit_bunches(locations, gamma=config.gamma, seed=config.seed)
        return initial_manifold(bunches.means, method=config.ellipse, lam=config.lam, seed=config.seed,
                                order=config.order, normalise=config.normalise,
                                append_ellipse=config.append_ellipse)
    except (BunchError, EllipseError) as exc:
        raise FeatureError(str(exc)) from None


def image_features(rgb: np.ndarray, mask: np.ndarray | None = None,
                   config: FeatureConfig = FeatureConfig(), raw: bool = True) -> dict:
    """Query features of one image: (H, W, 3) uint8 RGB, optional (H, W) mask or
    region of interest. Returns {"vector": (config.dims,) float64, "eccentricity":
    float, "keypoints": int, "raw": (raw_size^2,) uint8 (when ``raw``)};
    FeatureError if SIFT finds too few keypoints."""
    rgb = np.asarray(rgb)
    if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
        raise FeatureError(f"expected an (H, W, 3) uint8 RGB image, got {rgb.dtype} {rgb.shape}")
    small, small_mask = working_image(rgb, mask, config.max_side, config.min_side)
    locations = sift_locations(small, small_mask)
    if len(locations) < 2 * config.gamma:
        raise FeatureError(f"SIFT found {len(locations)} keypoints, need at least {2 * config.gamma}")
    vector, ecc = manifold_from_keypoints(locations, config)
    out = {"vector": vector, "eccentricity": ecc, "keypoints": len(locations)}
    if raw:
        out["raw"] = raw_vector(rgb, mask, config.raw_size)
    return out



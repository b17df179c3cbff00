"""SMM's part-based representation (Mei, Liu, Hero & Savarese, CVPR 2011; docs/method.md).

A *local feature* is a SIFT keypoint inside the object's (visible) mask: its
appearance (RootSIFT, reduced by PCA) and its geometry (its image position in an
object-centred frame: minus the mask's centroid, over the square root of the
mask's area, so translation and scale of the object drop out). A *part* is one
component of the joint appearance-geometry distribution of the training
features: a Gaussian with diagonal covariance found by k-means in the joint
space ("a PDF of the joint appearance and geometry", as the SPM paper describes
SMM's parts). In an image a part is *present* when some feature lies within its
Mahalanobis radius, and is then located at the nearest such feature.
"""

from __future__ import annotations

import numpy as np
from scipy.cluster.vq import kmeans2

from spm_model.errors import ModelError
from spm_model.base.feature_memo import memoized

UPSAMPLE_BELOW = 200   # images whose longest side is shorter are upsampled before SIFT (upsample_factor)
PRESENCE_QUANTILE = 0.5  # a part's radius: this quantile of its members' Mahalanobis distances


def upsample_factor(shape) -> int:
    """The whole factor an image of ``shape`` (H, W, ...) is upsampled by before SIFT: 1 from
    UPSAMPLE_BELOW pixels (longest side) up, 2 from 100, and below that the least factor that
    brings the longest side to UPSAMPLE_BELOW (a 32-pixel COIL image: 7), as SIFT finds few
    keypoints on small objects."""
    longest = max(int(shape[0]), int(shape[1]))
    return 1 if longest >= UPSAMPLE_BELOW else max(2, -(-UPSAMPLE_BELOW // max(longest, 1)))


def mask_frame(mask: np.ndarray):
    """(H, W) bool -> centroid (2,) pixels (x, y; OpenCV centres) and scale (float,
    pixels: sqrt of the mask's area); None when the mask is empty."""
    mask = np.asarray(mask, dtype=bool)
    area = int(np.count_nonzero(mask))
    if area == 0:
        return None
    # Whole-number sums of the pixel indices, divided once: the same floats as the mean of
    # np.nonzero's indices (exact below 2**53), without listing every pixel.
    x = int(np.dot(np.count_nonzero(mask, axis=0), np.arange(mask.shape[1])))
    y = int(np.dot(np.count_nonzero(mask, axis=1), np.arange(mask.shape[0])))
    return np.array([x / area, y / area]), float(np.sqrt(area))


def local_features(rgb: np.ndarray, mask: np.ndarray, max_features: int = 80):
    """One image's local features: ``geometry`` (N, 2) object-centred positions (pixels
    minus the mask centroid, over sqrt(mask area); dimensionless) and ``appearance``
    (N, 128) float32 RootSIFT descriptors, the ``max_features`` strongest keypoints
    inside ``mask``. Images under 200 px are upsampled first (upsample_factor). Empty arrays
    when the mask is empty or nothing is found."""
    geometry, sift = _local_sift(rgb, mask, max_features)
    return geometry, root_sift(sift)


def remembered_local_features(rgb: np.ndarray, mask: np.ndarray, max_features: int = 80):
    """local_features, remembered per image (spm_model/base/feature_memo.py: a benchmark
    shows SMM each frame in several folds and runs); the SIFT descriptors are kept, as
    uint8 when exact (OpenCV's values are whole numbers 0..255)."""
    def compute():
        geometry, sift = _local_sift(rgb, mask, max_features)
        small = sift.astype(np.uint8)
        return geometry, small if np.array_equal(small, sift) else sift

    factor = upsample_factor(np.shape(rgb))
    # Images upsampled more than twice (under 100 px) name their factor: entries of larger
    # images keep the key they had when every small image was doubled.
    kind = ("smm-local", int(max_features)) + ((("upsample", factor),) if factor > 2 else ())
    geometry, sift = memoized(kind, (rgb, mask), compute)
    return geometry, root_sift(sift)


def _local_sift(rgb, mask, max_features: int):
    """local_features with the plain SIFT descriptors (N, 128) float32."""
    import cv2

    frame = mask_frame(mask)
    if frame is None:
        return np.zeros((0, 2)), np.zeros((0, 128), np.float32)
    gray = cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2GRAY)
    cv_mask = np.asarray(mask, dtype=np.uint8) * 255
    scale = float(upsample_factor(gray.shape))
    if scale != 1.0:
        gray = cv2.resize(gray, None, fx=scale, fy=scale, interpolation=cv2.INTER_LINEAR)
        cv_mask = cv2.resize(cv_mask, None, fx=scale, fy=scale, interpolation=cv2.INTER_NEAREST)
    keypoints, desc = cv2.SIFT_create(nfeatures=max_features).detectAndCompute(gray, cv_mask)
    if not keypoints:
        return np.zeros((0, 2)), np.zeros((0, 128), np.float32)
    # OpenCV centres: pixel x in the upsampled image is at (x + 0.5) / scale - 0.5 in the original.
    xy = (np.array([k.pt for k in keypoints]) + 0.5) / scale - 0.5
    centroid, size = frame
    return (xy - centroid) / size, desc


def root_sift(desc: np.ndarray) -> np.ndarray:
    """(N, 128) SIFT -> RootSIFT (Arandjelovic & Zisserman 2012): l1-normalised, square
    root; (N, 128) float32 of unit l2 norm."""
    desc = np.asarray(desc, dtype=np.float32)
    desc = desc / np.maximum(desc.sum(axis=1, keepdims=True), 1e-12)
    return np.sqrt(desc)


class PartCodebook:
    """The candidate parts: PCA of the appearance, the joint space's scaling, and per
    part a centre and a diagonal spread in that space (learned state, arrays only)."""

    def __init__(self, mean, basis, appearance_scale, geometry_scale, centres, spreads, radii):
        self.mean, self.basis = mean, basis                     # (128,), (128, d)
        self.appearance_scale, self.geometry_scale = appearance_scale, geometry_scale
        self.centres, self.spreads, self.radii = centres, spreads, radii  # (P, d+2) x2, (P,)

    @property
    def size(self) -> int:
        return len(self.centres)

    def joint(self, geometry: np.ndarray, appearance: np.ndarray) -> np.ndarray:
        """(N, 2) geometry and (N, 128) appearance -> (N, d + 2) joint coordinates."""
        a = (np.asarray(appearance, np.float64) - self.mean) @ self.basis / self.appearance_scale
        return np.hstack([a, np.asarray(geometry, np.float64) * self.geometry_scale])

    def mahalanobis(self, joint: np.ndarray) -> np.ndarray:
        """(N, d + 2) -> (N, P) squared Mahalanobis distances to every part."""
        diff = joint[:, None, :] - self.centres[None]
        np.multiply(diff, diff, out=diff)            # in place: this is SMM's hottest loop
        return np.einsum("npd,pd->np", diff, 1.0 / self.spreads)

    def detect(self, geometry: np.ndarray, appearance: np.ndarray):
        """One image's parts: ``presence`` (P,) bool (some feature within the part's
        radius) and ``location`` (P, 2) object-centred position of the nearest such
        feature (0 where absent)."""
        presence = np.zeros(self.size, dtype=bool)
        location = np.zeros((self.size, 2))
        if len(geometry) == 0:
            return presence, location
        d2 = self.mahalanobis(self.joint(geometry, appearance))
        best = d2.argmin(axis=0)
        presence = d2[best, np.arange(self.size)] <= self.radii
        location[presence] = np.asarray(geometry)[best[presence]]
        return presence, location


def fit_codebook(geometry, appearance, parts: int, dims: int = 16, geometry_weight: float = 4.0,
                 seed: int = 0) -> PartCodebook:
    """Learn ``parts`` candidate parts from pooled training features: geometry (N, 2),
    appearance (N, 128). Appearance is reduced to ``dims`` PCA components and scaled to
    unit mean variance per component; geometry to unit variance per axis times
    ``geometry_weight``; k-means (k-means++, seeded) then gives each part its centre,
    per-axis spread (variance of its members plus a 1e-3 floor) and radius (the median
    of its members' squared Mahalanobis distances)."""
    geometry = np.asarray(geometry, np.float64)
    appearance = np.asarray(appearance, np.float64)
    if len(geometry) < 2 * parts:
        raise ModelError(f"SMM needs at least {2 * parts} local features to learn {parts} parts, got "
                         f"{len(geometry)}; give more training frames with textured objects, or fewer parts")
    mean = appearance.mean(axis=0)
    _, _, vt = np.linalg.svd(appearance - mean, full_matrices=False)
    basis = vt[:dims].T
    reduced = (appearance - mean) @ basis
    appearance_scale = float(np.sqrt(reduced.var(axis=0).mean())) or 1.0
    geometry_scale = geometry_weight / max(float(geometry.std(axis=0).mean()), 1e-6)
    joint = np.hstack([reduced / appearance_scale, geometry * geometry_scale])
    seeds = kmeans_plus_plus(joint, parts, np.random.default_rng(seed))
    centres, labels = kmeans2(joint, seeds, minit="matrix", iter=20)
    spreads = np.full_like(centres, 1e-3)
    radii = np.zeros(parts)
    for k in range(parts):
        members = joint[labels == k]
        if len(members) >= 2:
            spreads[k] += members.var(axis=0)
            d2 = np.sum((members - centres[k]) ** 2 / spreads[k], axis=1)
            radii[k] = np.quantile(d2, PRESENCE_QUANTILE)
    return PartCodebook(mean, basis, appearance_scale, geometry_scale, centres, spreads, radii)


def kmeans_plus_plus(data: np.ndarray, k: int, rng: np.random.Generator) -> np.ndarray:
    """(k, d) k-means++ seeds of ``data`` (n, d): scipy.cluster.vq.kmeans2's ``minit="++"``, the same
    draws from ``rng`` and the same centres, bit for bit (tested), but each point's least squared
    distance to the centres so far is kept and lowered by the newest one, where scipy measures it
    to every centre again (k-squared work: 5 of SMM's 14 s of fit in a split of 960 frames)."""
    from scipy.spatial.distance import cdist

    seeds = np.empty((int(k), data.shape[1]))
    seeds[0] = data[rng.integers(data.shape[0])]
    least = None
    for i in range(1, int(k)):
        newest = cdist(seeds[i - 1:i], data, metric="sqeuclidean")[0]
        least = newest if least is None else np.minimum(least, newest)
        cumulative = (least / least.sum()).cumsum()
        seeds[i] = data[int(np.searchsorted(cumulative, rng.uniform()))]
    return seeds

"""SIFT keypoints, with outliers removed by a homography RANSAC (paper §2, §2.1).

The paper does not say between which images the homography is fitted. Our rule
(docs/method.md): a training frame is matched with its 5-degree neighbour on the
camera path, and only its keypoints that are inliers of the RANSAC homography
between the two are kept; on a single query image there is no neighbour, so all
keypoints inside the object's mask (or a region of interest) are kept.
"""

from __future__ import annotations

import numpy as np

RATIO = 0.8            # Lowe's ratio test
RANSAC_PIXELS = 3.0    # reprojection threshold


def _gray_and_mask(rgb, mask):
    import cv2

    gray = cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2GRAY)
    return gray, None if mask is None else (np.asarray(mask) > 0).astype(np.uint8) * 255


def sift_keypoints(rgb: np.ndarray, mask: np.ndarray | None = None):
    """(H, W, 3) uint8 RGB, optional (H, W) mask -> locations (N, 2) float64 pixels
    (x, y; OpenCV centres) and descriptors (N, 128) float32, keypoints inside the mask."""
    import cv2

    keypoints, descriptors = cv2.SIFT_create().detectAndCompute(*_gray_and_mask(rgb, mask))
    if not keypoints:
        return np.zeros((0, 2)), np.zeros((0, 128), np.float32)
    return np.array([k.pt for k in keypoints], dtype=np.float64), descriptors.astype(np.float32)


def sift_locations(rgb: np.ndarray, mask: np.ndarray | None = None) -> np.ndarray:
    """sift_keypoints' locations (N, 2) alone, the same keypoints in the same order: the
    query rule needs no descriptors, and computing them was a third of SIFT's time."""
    import cv2

    keypoints = cv2.SIFT_create().detect(*_gray_and_mask(rgb, mask))
    return np.array([k.pt for k in keypoints], dtype=np.float64).reshape(-1, 2)


def homography_inliers(loc_a, desc_a, loc_b, desc_b, ratio=RATIO, threshold=RANSAC_PIXELS):
    """(N_a,) bool: keypoints of A matched to B (ratio test) and consistent with the
    RANSAC homography A -> B; all False when fewer than 4 matches survive."""
    import cv2

    keep = np.zeros(len(loc_a), dtype=bool)
    if len(loc_a) < 4 or len(loc_b) < 4:
        return keep
    pairs = cv2.BFMatcher(cv2.NORM_L2).knnMatch(desc_a, desc_b, k=2)
    good = [p[0] for p in pairs if len(p) == 2 and p[0].distance < ratio * p[1].distance]
    if len(good) < 4:
        return keep
    src = np.float32([loc_a[m.queryIdx] for m in good])
    dst = np.float32([loc_b[m.trainIdx] for m in good])
    H, inliers = cv2.findHomography(src, dst, cv2.RANSAC, threshold)
    if H is None:
        return keep
    keep[[m.queryIdx for m, ok in zip(good, inliers.ravel()) if ok]] = True
    return keep


def frame_keypoints(rgb, mask=None, neighbour_rgb=None, neighbour_mask=None) -> np.ndarray:
    """Keypoint locations (N, 2) of one frame by the rule above: RANSAC inliers against
    the path neighbour when one is given (training), else all inside the mask (query)."""
    if neighbour_rgb is None:
        return sift_locations(rgb, mask)
    loc, desc = sift_keypoints(rgb, mask)
    loc_b, desc_b = sift_keypoints(neighbour_rgb, neighbour_mask)
    return loc[homography_inliers(loc, desc, loc_b, desc_b)]

"""Image helpers every method may use (pure numpy + OpenCV)."""

from __future__ import annotations

import numpy as np


def raw_vector(rgb: np.ndarray, mask: np.ndarray | None, size: int) -> np.ndarray:
    """(size * size,) uint8: the grey bounding box of the mask (whole image without
    one), resized to size x size; the PCA and LS baselines' input."""
    import cv2

    gray = cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2GRAY)
    if mask is not None and np.any(mask):
        rows, cols = np.flatnonzero(np.any(mask, axis=1)), np.flatnonzero(np.any(mask, axis=0))
        gray = gray[rows[0]: rows[-1] + 1, cols[0]: cols[-1] + 1]
    return cv2.resize(gray, (size, size), interpolation=cv2.INTER_AREA).ravel()



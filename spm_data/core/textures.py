"""Seeded procedural textures that give SIFT something to find on small renders.

A texture is a 3 x 2 atlas of 256-pixel tiles (meshes.py maps the six box
projections onto it), filled with high-contrast blobs, bars and rings whose
sizes suit objects about 60 pixels across in a 128 x 128 render.
"""

from __future__ import annotations

import numpy as np

TILE = 256
SHAPE = (2 * TILE, 3 * TILE, 3)  # rows, cols, RGB


def _colour(rng, dark: bool):
    base = rng.integers(0, 90, 3) if dark else rng.integers(150, 256, 3)
    return tuple(int(c) for c in base)


def procedural_texture(rng: np.random.Generator, shapes: int = 480) -> np.ndarray:
    """(512, 768, 3) uint8 RGB texture drawn from ``rng`` (same state, same image)."""
    import cv2

    image = np.empty(SHAPE, dtype=np.uint8)
    image[:] = np.asarray(_colour(rng, dark=rng.random() < 0.5), dtype=np.uint8)
    h, w = SHAPE[:2]
    for _ in range(shapes):
        kind = rng.integers(0, 4)
        colour = _colour(rng, dark=rng.random() < 0.5)
        cx, cy = int(rng.integers(0, w)), int(rng.integers(0, h))
        size = int(rng.integers(4, 22))
        if kind == 0:
            cv2.circle(image, (cx, cy), size, colour, -1, lineType=cv2.LINE_AA)
        elif kind == 1:
            dx, dy = int(rng.integers(5, 30)), int(rng.integers(5, 30))
            cv2.rectangle(image, (cx, cy), (cx + dx, cy + dy), colour, -1)
        elif kind == 2:
            angle = rng.uniform(0, np.pi)
            end = (int(cx + 2 * size * np.cos(angle)), int(cy + 2 * size * np.sin(angle)))
            cv2.line(image, (cx, cy), end, colour, int(rng.integers(3, 9)), lineType=cv2.LINE_AA)
        else:
            cv2.circle(image, (cx, cy), size, colour, int(rng.integers(3, 7)), lineType=cv2.LINE_AA)
    return image

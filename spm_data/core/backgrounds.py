"""Backgrounds composited behind a render: black, a colour, or seeded crops of images from a folder."""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path

import numpy as np

from spm_data.errors import SpecError

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".ppm", ".tif", ".tiff")


@lru_cache(maxsize=4)
def _image_files(folder: str) -> tuple[Path, ...]:
    path = Path(folder)
    if not path.is_dir():
        raise SpecError(f"background.folder: no such folder {folder}")
    files = tuple(sorted(p for p in path.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES))
    if not files:
        raise SpecError(f"background.folder: no images ({' '.join(IMAGE_SUFFIXES)}) in {folder}")
    return files


def background_image(spec, rng: np.random.Generator, kind: str | None = None) -> np.ndarray | None:
    """(H, W, 3) uint8 background of ``kind`` (default: the spec's background.kind) for
    one frame, or None for black. "color" is the spec's colour, unless randomised
    (``kind`` given): then a random one, as are "gradient", "checker" and "noise"."""
    bg = spec.background
    h, w = spec.image.height, spec.image.width
    kind = kind or bg.kind
    if kind == "black":
        return None
    if kind == "color" and kind == bg.kind and not spec.randomize.backgrounds:
        return np.broadcast_to(np.round(np.asarray(bg.color) * 255).astype(np.uint8), (h, w, 3))
    if kind != "images":
        return procedural_background(kind, rng, h, w)
    import cv2

    folder = Path(spec.base_dir) / bg.folder
    files = _image_files(str(folder))
    path = files[int(rng.integers(len(files)))]
    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if image is None:
        raise SpecError(f"background.folder: cannot read image {path}")
    image = cv2.cvtColor(image, cv2.COLOR_BGR2RGB)
    # A random crop of the target aspect, at least half the short side, resized to the frame.
    ih, iw = image.shape[:2]
    scale = rng.uniform(0.5, 1.0) * min(ih / h, iw / w)
    ch, cw = max(1, int(h * scale)), max(1, int(w * scale))
    y0, x0 = int(rng.integers(0, ih - ch + 1)), int(rng.integers(0, iw - cw + 1))
    return cv2.resize(image[y0:y0 + ch, x0:x0 + cw], (w, h), interpolation=cv2.INTER_AREA)


def composite(rgb: np.ndarray, alpha: np.ndarray, background: np.ndarray | None) -> np.ndarray:
    """``rgb`` premultiplied over black (H, W, 3) uint8, ``alpha`` (H, W) float32 -> over ``background``."""
    if background is None:
        return rgb
    out = rgb.astype(np.float32) + (1.0 - alpha[..., None]) * background.astype(np.float32)
    return np.clip(np.round(out), 0, 255).astype(np.uint8)


def procedural_background(kind: str, rng: np.random.Generator, height: int, width: int) -> np.ndarray:
    """(height, width, 3) uint8 seeded pattern: ``"color"`` (one random colour),
    ``"gradient"`` (two colours along a random direction), ``"checker"`` (two colours,
    random cell size 4..32 px and phase) or ``"noise"`` (smooth value noise: a random
    4..16-cell grid of colours, bicubically enlarged)."""
    import cv2

    a, b = rng.uniform(0, 255, 3), rng.uniform(0, 255, 3)
    v, u = np.mgrid[0:height, 0:width].astype(np.float64)
    if kind == "color":
        image = np.broadcast_to(a, (height, width, 3))
    elif kind == "gradient":
        angle = rng.uniform(0, 2 * np.pi)
        s = u * np.cos(angle) + v * np.sin(angle)
        s = (s - s.min()) / max(np.ptp(s), 1e-9)
        image = a + s[..., None] * (b - a)
    elif kind == "checker":
        cell = int(rng.integers(4, 33))
        du, dv = rng.integers(0, cell, 2)
        odd = (((u + du) // cell + (v + dv) // cell) % 2)[..., None]
        image = np.where(odd > 0, b, a)
    elif kind == "noise":
        cells = int(rng.integers(4, 17))
        grid = rng.uniform(0, 255, (cells, cells, 3)).astype(np.float32)
        image = cv2.resize(grid, (width, height), interpolation=cv2.INTER_CUBIC)
    else:
        raise SpecError(f"unknown background kind {kind!r}")
    return np.clip(np.round(image), 0, 255).astype(np.uint8)

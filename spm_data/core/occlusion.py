"""Black-rectangle occlusions with exact coverage of the object's mask (pure numpy).

The covered fraction is counted from the mask, pixel by pixel: for a random
centre, every rectangle size is scored at once with a summed-area table of the
still-visible mask, and a size whose coverage lies within ``tolerance`` of the
target is drawn at random. Frames whose object is too small or thin to reach the
target within ``tries`` centres keep the closest coverage found, and say so.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from spm_data.errors import Option, SpmError

DEFAULT_TOLERANCE = 0.005


@dataclass(frozen=True)
class Occlusion:
    """rects (R, 4) int32 ``x0, y0, x1, y1`` half-open pixel bounds; fraction of mask
    pixels covered by their union; reached: whether |fraction - target| <= tolerance."""

    rects: np.ndarray
    fraction: float
    target: float
    reached: bool


def _summed_area(mask: np.ndarray) -> np.ndarray:
    """(H + 1, W + 1) int32 table: table[y, x] = mask[:y, :x].sum()."""
    table = np.zeros((mask.shape[0] + 1, mask.shape[1] + 1), dtype=np.int32)
    np.cumsum(np.cumsum(mask, axis=0, dtype=np.int32), axis=1, out=table[1:, 1:])
    return table


def _best_rect_at(table, cx, cy, need, band, rng, box, size):
    """Among rectangles centred on (cx, cy), one covering ``need`` pixels of the
    table's mask: a random one covering a count in ``band`` (lo, hi), else the
    closest to ``need``. Sizes reach the object's bounding box ``box`` (x0, y0,
    x1, y1) and no further: beyond it a rectangle covers no more of the object.
    ``table`` is the summed-area table of the mask inside ``box`` (the mask is
    empty outside it); ``size`` the image's (H, W). Returns (x0, y0, x1, y1, covered),
    in image pixels. (cx, cy) lies inside ``box``, so each bound is clipped on one side only.
    """
    h, w = size
    half_w = np.arange(0, max(cx - box[0], box[2] - 1 - cx) + 1)  # every rectangle half-size at once
    half_h = np.arange(0, max(cy - box[1], box[3] - 1 - cy) + 1)
    x0, x1 = np.maximum(cx - half_w, 0), np.minimum(cx + half_w + 1, w)
    y0, y1 = np.maximum(cy - half_h, 0), np.minimum(cy + half_h + 1, h)
    # The table's indices: the same rectangles clipped to the box (nothing to count outside).
    tx0, tx1 = np.maximum(x0, box[0]) - box[0], np.minimum(x1, box[2]) - box[0]
    ty0, ty1 = np.maximum(y0, box[1]) - box[1], np.minimum(y1, box[3]) - box[1]
    rows0, rows1 = table[ty0], table[ty1]  # (len(half_h), box width + 1)
    covered = (rows1[:, tx1] - rows0[:, tx1] - rows1[:, tx0] + rows0[:, tx0]).T  # (len(half_w), len(half_h))
    ok = np.flatnonzero((covered >= band[0]) & (covered <= band[1]))
    # ok[rng.integers(len(ok))] draws as rng.choice(ok) does, without its overhead
    pick = int(ok[rng.integers(len(ok))]) if len(ok) else int(np.argmin(np.abs(covered - need)))
    i, j = divmod(pick, covered.shape[1])
    return int(x0[i]), int(y0[j]), int(x1[i]), int(y1[j]), int(covered[i, j])


def _state(obj: np.ndarray):
    """What a rectangle is placed on: the still visible pixels (flat indices), their bounding
    box (x0, y0, x1, y1) and the summed-area table inside it (None, None when none is left)."""
    flat = np.flatnonzero(obj)
    if len(flat) == 0:
        return flat, None, None
    rows = np.flatnonzero(obj.any(axis=1))
    cols = np.flatnonzero(obj.any(axis=0))
    box = (int(cols[0]), int(rows[0]), int(cols[-1]) + 1, int(rows[-1]) + 1)
    return flat, box, _summed_area(obj[box[1]:box[3], box[0]:box[2]])


def occlude_mask(mask: np.ndarray, target: float, rng: np.random.Generator, rects: int = 1,
                 tries: int = 8, tolerance: float = DEFAULT_TOLERANCE, bounds=(0.0, 1.0)) -> Occlusion:
    """Place ``rects`` rectangles so their union covers ``target`` of ``mask``.

    mask: (H, W) nonzero on the object. target in [0, 1]. Each rectangle takes an
    equal share of what is still to cover; centres are random object pixels.
    ``reached`` means within ``tolerance`` of the target and inside ``bounds``
    (the requested [min, max]), or, for bounds narrower than 2 x tolerance,
    within ``tolerance`` of the target.
    """
    if not 0.0 <= target <= 1.0:
        raise SpmError(f"occlusion target must lie in [0, 1], got {target}")
    if rects < 1:
        raise SpmError(f"rects must be >= 1, got {rects}")
    obj = np.asarray(mask) > 0
    total = int(np.count_nonzero(obj))
    out = np.zeros((rects, 4), dtype=np.int32)
    if total == 0:
        return Occlusion(out, 0.0, float(target), target == 0.0)
    if target == 0.0:
        return Occlusion(out, 0.0, 0.0, True)
    if bounds[1] - bounds[0] >= 2 * tolerance:
        lo_px, hi_px = max(bounds[0], target - tolerance) * total, min(bounds[1], target + tolerance) * total
    else:  # a range narrower than the tolerance (min 0.3, max 0.3): target +- tolerance
        lo_px, hi_px = (target - tolerance) * total, (target + tolerance) * total
    first = _state(obj)  # the same for every try
    best = None
    for _ in range(tries):
        placed, covered = _place_rects(obj, first, rects, target * total, (lo_px, hi_px), rng)
        fraction = covered / total
        inside = lo_px <= covered <= hi_px
        if best is None or (inside, -abs(fraction - target)) > (best.reached, -abs(best.fraction - target)):
            best = Occlusion(placed, fraction, float(target), inside)
        if best.reached:
            break
    return best


def _place_rects(obj, first, rects: int, goal: float, band: tuple, rng) -> tuple[np.ndarray, int]:
    """One try: ``rects`` rectangles, each covering its share of ``goal`` pixels of what the
    ones before left visible (the last closing the pixel band (lo, hi)); returns the (R, 4)
    rectangles and the pixels they cover."""
    lo_px, hi_px = band
    visible = obj
    placed = np.zeros((rects, 4), dtype=np.int32)
    covered = 0
    for k in range(rects):
        left = rects - k
        need = (goal - covered) / left
        # Each rectangle gets its share of the band; the last one closes it exactly.
        share = (need - (goal - lo_px) / rects, need + (hi_px - goal) / rects) \
            if left > 1 else (lo_px - covered, hi_px - covered)
        flat, box, table = first if k == 0 else _state(visible)
        if len(flat) == 0:
            break
        cy, cx = divmod(int(flat[rng.integers(len(flat))]), visible.shape[1])
        x0, y0, x1, y1, got = _best_rect_at(table, cx, cy, need, share, rng, box, visible.shape)
        placed[k] = (x0, y0, x1, y1)
        if k < rects - 1:  # what the next rectangle sees
            visible = visible.copy() if k == 0 else visible
            visible[y0:y1, x0:x1] = False
        covered += got
    return placed, covered


def apply_occlusion(rgb: np.ndarray, mask: np.ndarray, rects: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Black out ``rects`` in ``rgb``; returns (occluded rgb (H, W, 3) uint8, visible_mask (H, W) uint8)."""
    rgb = np.array(rgb, copy=True)
    visible = (np.asarray(mask) > 0).astype(np.uint8)
    black_out(rgb, visible, rects=rects)
    return rgb, visible


def black_out(*images: np.ndarray, rects: np.ndarray) -> None:
    """Set ``rects`` ((R, 4) x0, y0, x1, y1) to 0 in each (H, W, ...) image, in place."""
    for x0, y0, x1, y1 in np.asarray(rects).reshape(-1, 4):
        for image in images:
            image[y0:y1, x0:x1] = 0


def occlude_image(rgb: np.ndarray, mask: np.ndarray, rng: np.random.Generator, low: float = 0.0,
                  high: float = 0.6, rects: int = 1, tolerance: float = DEFAULT_TOLERANCE):
    """One image in memory: draw a target uniformly in [low, high], occlude.

    rgb (H, W, 3) uint8, mask (H, W). Returns (occluded rgb, visible_mask, Occlusion).
    The model's evaluation uses this to sweep occlusion levels without files.
    """
    check_range(low, high)
    target = float(rng.uniform(low, high)) if high > low else float(low)
    occ = occlude_mask(mask, target, rng, rects=rects, tolerance=tolerance, bounds=(low, high))
    image, visible = apply_occlusion(rgb, mask, occ.rects)
    return image, visible, occ


def check_range(low: float, high: float) -> None:
    """SpmError unless 0 <= low <= high <= 1, naming the options by key (min, max: Option)."""
    if not (0.0 <= low <= 1.0 and 0.0 <= high <= 1.0):
        raise SpmError("occlusion fractions must lie in [0, 1]: got ", Option("min"), f" {low}, ", Option("max"),
                       f" {high}")
    if low > high:
        raise SpmError(Option("min"), f" {low} is above ", Option("max"), f" {high}")

import numpy as np
import pytest

from spm_data.errors import SpmError
from spm_data.core.occlusion import apply_occlusion, black_out, occlude_image, occlude_mask


def disc(h=128, w=128, r=30, cx=60, cy=70):
    yy, xx = np.mgrid[0:h, 0:w]
    return ((xx - cx) ** 2 + (yy - cy) ** 2 <= r * r).astype(np.uint8)


def covered(mask, rects):
    cover = np.zeros(mask.shape, bool)
    for x0, y0, x1, y1 in rects:
        cover[y0:y1, x0:x1] = True
    return (cover & (mask > 0)).sum() / (mask > 0).sum()


@pytest.mark.parametrize("target", [0.05, 0.3, 0.6, 0.95])
@pytest.mark.parametrize("rects", [1, 3])
def test_coverage_is_exact_and_measured_from_the_mask(target, rects):
    rng = np.random.default_rng(1)
    mask = disc()
    for _ in range(20):
        occ = occlude_mask(mask, target, rng, rects=rects)
        assert occ.reached
        assert abs(occ.fraction - target) <= 0.005
        assert occ.fraction == pytest.approx(covered(mask, occ.rects), abs=1e-12)  # counted, not estimated
        assert occ.rects.shape == (rects, 4) and occ.rects.dtype == np.int32
        assert np.all(occ.rects[:, 2] > occ.rects[:, 0]) and np.all(occ.rects[:, 3] > occ.rects[:, 1])
        assert np.all(occ.rects[:, [0, 2]] <= 128) and np.all(occ.rects >= 0)


def test_fractions_never_leave_the_requested_range():
    rng = np.random.default_rng(2)
    mask = disc(r=12)  # small: each pixel is 0.2% of the object
    for _ in range(200):
        _, _, occ = occlude_image(np.zeros((128, 128, 3), np.uint8), mask, rng, 0.2, 0.6, rects=2)
        assert 0.2 <= occ.fraction <= 0.6 and occ.reached


def test_sizes_and_places_vary():
    rng = np.random.default_rng(0)
    boxes = {tuple(occlude_mask(disc(), 0.3, rng).rects[0]) for _ in range(30)}
    assert len(boxes) > 20
    widths = {b[2] - b[0] for b in boxes}
    assert max(widths) - min(widths) > 10


def test_thin_object_reports_unreachable_and_keeps_the_closest():
    mask = np.zeros((64, 64), np.uint8)
    mask[10:50:6, 5:60] = 1  # seven thin stripes: a rectangle covering 50% exactly is rare
    occ = occlude_mask(mask, 0.5, np.random.default_rng(3), tries=1, tolerance=0.0001)
    assert occ.fraction == pytest.approx(covered(mask, occ.rects))
    assert occ.reached == (abs(occ.fraction - 0.5) <= 0.0001)
    assert abs(occ.fraction - 0.5) < 0.1


def test_zero_target_and_empty_mask():
    occ = occlude_mask(disc(), 0.0, np.random.default_rng(0))
    assert occ.fraction == 0 and not occ.rects.any() and occ.reached
    occ = occlude_mask(np.zeros((8, 8)), 0.4, np.random.default_rng(0))
    assert occ.fraction == 0 and not occ.reached


def test_apply_blacks_out_rects_and_keeps_the_full_mask_separate():
    rgb = np.full((128, 128, 3), 200, np.uint8)
    mask = disc()
    image, visible, occ = occlude_image(rgb, mask, np.random.default_rng(5), 0.3, 0.3)
    x0, y0, x1, y1 = occ.rects[0]
    assert not image[y0:y1, x0:x1].any() and image[~np.isin(np.arange(128), range(y0, y1))].min() == 200
    assert visible.sum() == pytest.approx(mask.sum() * (1 - occ.fraction), abs=0.5)
    assert rgb.min() == 200  # input untouched
    again, _, _ = occlude_image(rgb, mask, np.random.default_rng(5), 0.3, 0.3)
    np.testing.assert_array_equal(image, again)


def test_bad_ranges():
    # The library names the options by key; the command line writes its flags (tests/cli/test_support.py).
    with pytest.raises(SpmError) as e:
        occlude_image(np.zeros((4, 4, 3), np.uint8), np.ones((4, 4)), np.random.default_rng(0), 0.0, 1.5)
    assert str(e.value) == "occlusion fractions must lie in [0, 1]: got min 0.0, max 1.5"
    with pytest.raises(SpmError) as e:
        occlude_image(np.zeros((4, 4, 3), np.uint8), np.ones((4, 4)), np.random.default_rng(0), 0.7, 0.6)
    assert str(e.value) == "min 0.7 is above max 0.6"
    assert e.value.named({"min": "--min"}) == "--min 0.7 is above max 0.6"   # a key without a name: as it is
    np.testing.assert_array_equal(apply_occlusion(np.ones((2, 2, 3), np.uint8), np.ones((2, 2)),
                                                  np.zeros((1, 4), np.int32))[1], np.ones((2, 2)))


def test_black_out_zeroes_each_rectangle_in_every_image_in_place():
    rgb = np.full((6, 8, 3), 7, np.uint8)
    visible = np.ones((6, 8), np.uint8)
    black_out(rgb, visible, rects=np.array([[1, 2, 3, 4], [6, 0, 8, 1]], np.int32))
    expected = np.ones((6, 8), np.uint8)
    expected[2:4, 1:3] = 0
    expected[0:1, 6:8] = 0
    np.testing.assert_array_equal(visible, expected)
    np.testing.assert_array_equal(rgb, 7 * expected[..., None].repeat(3, axis=2))
    rects = np.array([[1, 2, 3, 4], [6, 0, 8, 1]])
    again, vis = apply_occlusion(np.full((6, 8, 3), 7, np.uint8), np.ones((6, 8)), rects)
    np.testing.assert_array_equal(again, rgb)
    np.testing.assert_array_equal(vis, visible)


def test_placements_equal_the_straightforward_reference():
    """occlude_mask reuses the first rectangle's state across tries and draws with
    ok[rng.integers(len(ok))]: the same rectangles, coverage and draws as placing every
    try from scratch with rng.choice (the code before), on random blobs and settings."""
    for seed in range(60):
        rng = np.random.default_rng(seed)
        mask = np.zeros((40, 50), np.uint8)
        for _ in range(1 + seed % 3):
            y, x = rng.integers(0, 35), rng.integers(0, 45)
            mask[y:y + rng.integers(2, 20), x:x + rng.integers(2, 25)] = 1
        rects, target = 1 + seed % 3, float(rng.uniform(0.05, 0.9))
        got = occlude_mask(mask, target, np.random.default_rng(seed), rects=rects, bounds=(0.0, 1.0))
        want_rng = np.random.default_rng(seed)
        want = _reference_occlude(mask, target, want_rng, rects)
        np.testing.assert_array_equal(got.rects, want[0])
        assert (got.fraction, got.reached) == want[1:]


def _reference_occlude(mask, target, rng, rects, tries=8, tolerance=0.005):
    """The placement as first written (every try from scratch, rng.choice)."""
    obj = mask > 0
    total = int(obj.sum())
    lo_px, hi_px = max(0.0, target - tolerance) * total, min(1.0, target + tolerance) * total
    best = None
    for _ in range(tries):
        visible, placed, covered = obj.copy(), np.zeros((rects, 4), np.int32), 0
        for k in range(rects):
            left = rects - k
            need = (target * total - covered) / left
            band = (need - (target * total - lo_px) / rects, need + (hi_px - target * total) / rects) \
                if left > 1 else (lo_px - covered, hi_px - covered)
            flat = np.flatnonzero(visible)
            if len(flat) == 0:
                break
            cy, cx = divmod(int(flat[rng.integers(len(flat))]), visible.shape[1])
            rows, cols = np.flatnonzero(visible.any(axis=1)), np.flatnonzero(visible.any(axis=0))
            box = (int(cols[0]), int(rows[0]), int(cols[-1]) + 1, int(rows[-1]) + 1)
            table = np.zeros((box[3] - box[1] + 1, box[2] - box[0] + 1), np.int64)
            table[1:, 1:] = visible[box[1]:box[3], box[0]:box[2]].cumsum(0).cumsum(1)
            h, w = visible.shape
            half_w = np.arange(max(cx - box[0], box[2] - 1 - cx) + 1)
            half_h = np.arange(max(cy - box[1], box[3] - 1 - cy) + 1)
            x0, x1 = np.clip(cx - half_w, 0, w), np.clip(cx + half_w + 1, 0, w)
            y0, y1 = np.clip(cy - half_h, 0, h), np.clip(cy + half_h + 1, 0, h)
            tx0, tx1 = np.clip(x0, box[0], box[2]) - box[0], np.clip(x1, box[0], box[2]) - box[0]
            ty0, ty1 = np.clip(y0, box[1], box[3]) - box[1], np.clip(y1, box[1], box[3]) - box[1]
            cov = (table[ty1][:, tx1] - table[ty0][:, tx1] - table[ty1][:, tx0] + table[ty0][:, tx0]).T
            ok = np.flatnonzero((cov >= band[0]) & (cov <= band[1]))
            pick = rng.choice(ok) if len(ok) else int(np.argmin(np.abs(cov - need)))
            i, j = np.unravel_index(pick, cov.shape)
            placed[k] = (x0[i], y0[j], x1[i], y1[j])
            visible[y0[j]:y1[j], x0[i]:x1[i]] = False
            covered += int(cov[i, j])
        fraction, inside = covered / total, lo_px <= covered <= hi_px
        if best is None or (inside, -abs(fraction - target)) > (best[2], -abs(best[1] - target)):
            best = (placed, fraction, inside)
        if best[2]:
            break
    return best

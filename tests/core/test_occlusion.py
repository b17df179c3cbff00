import numpy as np
import pytest

from spm_data.errors import SpmError
from spm_data.core.occlusion import apply_occlusion, occlude_image, occlude_mask


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
    with pytest.raises(SpmError, match=r"must lie in \[0, 1\]"):
        occlude_image(np.zeros((4, 4, 3), np.uint8), np.ones((4, 4)), np.random.default_rng(0), 0.0, 1.5)
    with pytest.raises(SpmError, match="--min 0.7 is above --max 0.6"):
        occlude_image(np.zeros((4, 4, 3), np.uint8), np.ones((4, 4)), np.random.default_rng(0), 0.7, 0.6)
    np.testing.assert_array_equal(apply_occlusion(np.ones((2, 2, 3), np.uint8), np.ones((2, 2)),
                                                  np.zeros((1, 4), np.int32))[1], np.ones((2, 2)))

"""spm_model.methods.descriptors: the reference estimator's descriptor: HOG of the object's box (the
background zeroed), then the box's centre and size and K."""

import cv2
import numpy as np

from spm_model.methods.descriptors import GEOMETRY, HOG_SIZE, box_of, hog_descriptor, template_descriptor

K = np.array([[100.0, 0, 47.5], [0, 110.0, 39.5], [0, 0, 1]])


def scene(x0=30, y0=20, size=(24, 36)):
    """A textured rectangle (rows y0.., columns x0..; 24 x 36 by default) on noise, and its mask."""
    rng = np.random.default_rng(0)
    rgb = rng.integers(0, 255, (80, 96, 3)).astype(np.uint8)
    h, w = size
    texture = np.random.default_rng(1).integers(0, 255, (h, w, 3)).astype(np.uint8)
    rgb[y0:y0 + h, x0:x0 + w] = cv2.GaussianBlur(texture, (5, 5), 0)
    mask = np.zeros((80, 96), bool)
    mask[y0:y0 + h, x0:x0 + w] = True
    return rgb, mask


def test_box_of_a_mask():
    mask = np.zeros((10, 12), bool)
    mask[2:5, 3:10] = True                      # rows 2..4, columns 3..9
    assert box_of(mask) == (6.0, 3.0, 7.0)      # centre (u, v) in pixels, the longer side
    assert box_of(np.zeros((4, 4), bool)) is None


def test_template_descriptor_is_hog_then_the_boxes_geometry_and_k():
    rgb, mask = scene()
    d = template_descriptor(rgb, mask, K)
    assert d.shape == (HOG_SIZE + len(GEOMETRY),) == (3535,) and d.dtype == np.float32
    assert hog_descriptor().getDescriptorSize() == HOG_SIZE
    assert np.isfinite(d).all() and d[:HOG_SIZE].max() > 0
    np.testing.assert_array_equal(d[HOG_SIZE:], np.float32([47.5, 31.5, 36.0, 100.0, 110.0, 47.5, 39.5]))


def test_the_background_is_ignored_and_a_shift_moves_only_the_geometry():
    rgb, mask = scene()
    d = template_descriptor(rgb, mask, K)
    other = rgb.copy()
    other[~mask] = 255 - other[~mask]           # another background, the same object
    np.testing.assert_array_equal(template_descriptor(other, mask, K), d)
    moved_rgb, moved_mask = scene(x0=40, y0=30)
    moved = template_descriptor(moved_rgb, moved_mask, K)
    np.testing.assert_allclose(moved[:HOG_SIZE], d[:HOG_SIZE], atol=1e-5)
    np.testing.assert_array_equal(moved[HOG_SIZE:HOG_SIZE + 3], d[HOG_SIZE:HOG_SIZE + 3] + np.float32([10, 10, 0]))


def test_an_empty_mask_is_nan():
    rgb, _ = scene()
    assert np.isnan(template_descriptor(rgb, np.zeros((80, 96), bool), K)).all()

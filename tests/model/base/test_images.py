"""spm_model.base.images: the raw vector is the grey box of the mask."""

import numpy as np

from spm_model.base.images import raw_vector


def test_raw_vector_crops_the_mask_box():
    rgb = np.zeros((40, 60, 3), np.uint8)
    rgb[10:20, 30:50] = 200
    mask = (rgb[..., 0] > 0).astype(np.uint8)
    v = raw_vector(rgb, mask, 8)
    assert v.shape == (64,) and v.dtype == np.uint8 and (v == 200).all()   # the box fills the crop

"""Blender helpers that need no Blender: the sRGB curve and the log tail."""

import numpy as np

from spm_data.render.blender_scene import srgb_encode, tail


def test_srgb_encode_follows_the_standard_curve():
    linear = np.array([0.0, 0.0031308, 0.18, 0.5, 1.0, 1.7, -0.2])
    np.testing.assert_array_equal(srgb_encode(linear), [0, 10, 118, 188, 255, 255, 0])
    assert srgb_encode(np.zeros((2, 3, 3))).dtype == np.uint8


def test_tail_quotes_the_last_non_empty_lines(tmp_path):
    log = tmp_path / "blender.log"
    log.write_text("one\n\ntwo\nthree\n\nfour\n")
    assert tail(str(log)) == "three | four"  # the last three lines, the empty one dropped
    assert tail(str(tmp_path / "missing.log")) == ""

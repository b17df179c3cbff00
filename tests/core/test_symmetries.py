"""Symmetries: declared in a spec, expanded into rotations."""

import numpy as np
import pytest

from spm_data.errors import MeshError
from spm_data.core.symmetries import declared_symmetries, parse_symmetry, rotation


def test_declared_symmetries_expand_n_fold_turns():
    s = declared_symmetries(["z/90", "x/180", "y"])
    assert len(s.discrete) == 4   # 90, 180, 270 about z; 180 about x
    np.testing.assert_allclose(s.discrete[1], rotation([0, 0, 1], 180), atol=1e-12)
    np.testing.assert_array_equal(s.continuous[0], [0, 1, 0])
    with pytest.raises(MeshError, match="must divide 360"):
        declared_symmetries(["z/100"])


def test_parse_symmetry_reads_axis_and_turn():
    assert parse_symmetry("z") == ("z", None) and parse_symmetry(" x/120 ") == ("x", 120.0)
    for bad, message in (("w", "expected an axis"), ("z/", "must divide"), ("z/abc", "must divide"),
                         ("z/360", "must divide")):
        with pytest.raises(MeshError, match=message):
            parse_symmetry(bad)


def test_rotation_is_right_handed():
    np.testing.assert_allclose(rotation([0, 0, 1], 90) @ [1, 0, 0], [0, 1, 0], atol=1e-12)

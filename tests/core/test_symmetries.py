"""Symmetries: declared in a spec, expanded into rotations."""

import numpy as np
import pytest

from spm_data.errors import MeshError
from spm_data.core.symmetries import declared_symmetries, parse_symmetry, rotation


def test_declared_symmetries_expand_n_fold_turns():
    s = declared_symmetries(["z/90"])
    assert len(s.discrete) == 3 and not s.continuous   # 90, 180, 270 about z
    np.testing.assert_allclose(s.discrete[0], rotation([0, 0, 1], 90), atol=1e-12)
    with pytest.raises(MeshError, match="divide it"):
        declared_symmetries(["z/100"])


def in_(R, rotations):
    return any(np.allclose(R, S, atol=1e-9) for S in rotations)


def test_declared_turns_are_completed_to_their_group_each_once():
    two = declared_symmetries(["x/180", "y/180"]).discrete
    assert len(two) == 3 and in_(rotation([0, 0, 1], 180), two)   # x and y half turns make z's
    assert len(declared_symmetries(["z/180", "z/180"]).discrete) == 1
    assert len(declared_symmetries(["z/90", "x/180"]).discrete) == 7   # the square's 8 turns, less the identity
    assert len(declared_symmetries(["x/90", "z/90"]).discrete) == 23   # the cube's 24


def test_a_continuous_axis_absorbs_the_turns_about_it():
    s = declared_symmetries(["z", "z/180", "x/180", "z"])
    assert len(s.continuous) == 1
    assert len(s.discrete) == 2 and in_(rotation([1, 0, 0], 180), s.discrete) and in_(rotation([0, 1, 0], 180),
                                                                                      s.discrete)


def test_turns_that_make_no_finite_group_are_refused():
    with pytest.raises(MeshError, match="generate more than 120 rotations"):
        declared_symmetries(["z/90", "x/72"])


def test_parse_symmetry_reads_axis_and_turn():
    assert parse_symmetry("z") == ("z", None) and parse_symmetry(" x/120 ") == ("x", 120.0)
    for bad, message in (("w", "expected an axis"), ("z/", "divide it"), ("z/abc", "divide it"),
                         ("z/360", "less than 360 degrees")):
        with pytest.raises(MeshError, match=message):
            parse_symmetry(bad)


def test_rotation_is_right_handed():
    np.testing.assert_allclose(rotation([0, 0, 1], 90) @ [1, 0, 0], [0, 1, 0], atol=1e-12)

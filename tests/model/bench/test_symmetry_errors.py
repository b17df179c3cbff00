"""spm_model.bench.symmetry_errors: the paper's criteria up to declared symmetries."""

import numpy as np

from spm_data.core.poses import label_to_pose, pose_to_label
from spm_data.core.symmetries import NO_SYMMETRY, declared_symmetries, rotation
from spm_model.bench.symmetry_errors import nearest_equivalent, symmetric_errors


def _labels_turned(true, S):
    R, t = label_to_pose(true)
    return pose_to_label(R @ S, t)


def test_a_half_turn_of_a_box_is_no_error_and_a_quarter_turn_is():
    true = np.array([[20.0, -10.0, 35.0, 0.0, 0.0, 0.5], [-40.0, 5.0, 170.0, 0.01, 0.0, 0.6]])
    box = declared_symmetries(["x/180", "y/180", "z/180"])
    half = _labels_turned(true, rotation([0, 0, 1], 180))
    quarter = _labels_turned(true, rotation([0, 0, 1], 90))
    e = symmetric_errors(half, true, [box, box])
    np.testing.assert_allclose(e["geodesic_sym"], 0, atol=1e-6)
    np.testing.assert_allclose(e["rotation_max_sym"], 0, atol=1e-6)
    e = symmetric_errors(quarter, true, [box, box])
    np.testing.assert_allclose(e["geodesic_sym"], 90, atol=1e-6)
    e = symmetric_errors(half, true, [NO_SYMMETRY, None])
    assert np.isclose(e["geodesic_sym"][0], 180) and np.isnan(e["geodesic_sym"][1])


def test_a_continuous_axis_leaves_only_the_tilt_of_the_axis():
    rng = np.random.default_rng(0)
    true = np.column_stack([rng.uniform(-60, 60, (20, 3)), np.zeros((20, 2)), np.full(20, 0.5)])
    cup = declared_symmetries(["z"])
    spun = np.stack([_labels_turned(true[i:i + 1], rotation([0, 0, 1], a))[0]
                     for i, a in enumerate(rng.uniform(0, 360, 20))])
    np.testing.assert_allclose(symmetric_errors(spun, true, [cup] * 20)["geodesic_sym"], 0, atol=1e-5)
    tilted = np.stack([_labels_turned(true[i:i + 1], rotation([1, 0, 0], 7.0) @ rotation([0, 0, 1], 33))[0]
                       for i in range(20)])
    np.testing.assert_allclose(symmetric_errors(tilted, true, [cup] * 20)["geodesic_sym"], 7.0, atol=1e-5)


def test_nearest_equivalent_of_a_ball_is_the_estimate_and_no_estimate_fails():
    R = label_to_pose(np.array([[10.0, 20, 30, 0, 0, 1]]))[0]
    ball = declared_symmetries(["x", "y", "z"])
    np.testing.assert_allclose(nearest_equivalent(R.copy(), np.eye(3)[None], ball), R)
    e = symmetric_errors(np.full((1, 6), np.nan), np.zeros((1, 6)), [ball])
    assert e["rotation_max_sym"][0] == np.inf and np.isnan(e["geodesic_sym"][0])

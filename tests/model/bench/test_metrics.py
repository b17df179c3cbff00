"""spm_model.bench.metrics: the paper's success criteria, geodesic and per-DoF errors, measured
components only, the accuracy curve and its area."""

import numpy as np

from spm_data.core.poses import camera_poses, pose_to_label
from spm_model.bench.metrics import accuracy_curve, curve_auc, pose_errors, success_rate, summarise, tolerance_rate


def test_success_sums_the_absolute_wrapped_angle_errors():
    true = np.array([[90.0, 0, 179, 0, 0, 0.7]] * 4)
    pred = true.copy()
    pred[0, :3] = [91, 1, -179]        # 1 + 1 + 2 (across the wrap) = 4 degrees: success at 5, not at 3
    pred[1, :3] = [92, 2, 179]         # 4 again, in two angles
    pred[2, :3] = [90, 0, 174]         # exactly 5 (float noise must not decide): failure
    pred[3] = np.nan                   # no estimate: failure
    e = pose_errors(pred, true)
    assert np.allclose(e["rotation_sum"][:3], [4, 4, 5]) and np.isinf(e["rotation_sum"][3])
    s = summarise(e)
    assert s["frames"] == 4 and s["estimated"] == 3
    assert s["success_sum5"] == 50.0 and s["success_sum3"] == 0.0
    assert success_rate(np.array([4.9999999999, 5.0000000001]), 5) == 0.0


def test_geodesic_and_translation_errors():
    true = np.array([[90.0, 0, 0, 0, 0, 0.7]])
    pred = np.array([[90.0, 0, 30, 0.003, 0.004, 0.7]])   # 30 degrees about the camera's... any single axis
    e = pose_errors(pred, true)
    assert np.isclose(e["geodesic"][0], 30.0) and np.isclose(e["translation"][0], 0.005)


def test_only_measured_components_are_scored():
    true = np.array([[0.0, 0, 10, 0, 0, 1]])
    pred = np.array([[50.0, 50, 12, 9, 9, 9]])
    measured = np.array([[False, False, True, False, False, False]])   # e.g. COIL-100: azimuth only
    e = pose_errors(pred, true, measured)
    assert e["rotation_sum"][0] == 2.0 and np.isnan(e["geodesic"][0]) and np.isnan(e["translation"][0])
    nothing = pose_errors(pred, true, np.zeros((1, 6), bool))
    assert np.isnan(nothing["rotation_sum"][0]) and summarise(nothing)["success_sum5"] is None
    assert summarise(nothing)["success_tol5"] is None and summarise(e)["success_tol5"] == 100.0


def test_tolerance_is_every_angle_within_5_degrees_inclusive_across_the_wrap():
    true = np.array([[90.0, 0, 178, 0, 0, 0.7]] * 5)
    pred = true.copy()
    pred[0, :3] = [95, 0, 178]          # exactly 5 in one angle: within the tolerance (the adjacent grid view)
    pred[1, :3] = [95, -5, -177]        # 5, 5 and 5 across the +-180 wrap (178 -> -177): within
    pred[2, :3] = [90, 0, -176.9]       # 5.1 across the wrap: outside
    pred[3, :3] = [85.5, 0, 178]        # 4.5: within
    pred[4] = np.nan                    # no estimate: a failure
    e = pose_errors(pred, true)
    assert np.allclose(e["rotation_max"][:4], [5, 5, 5.1, 4.5]) and np.isinf(e["rotation_max"][4])
    s = summarise(e)
    assert s["success_tol5"] == 60.0           # 3 of 5
    assert s["success_sum5"] == 20.0           # only the 4.5 frame sums below 5
    # Float noise (1e-7 over) does not decide; a thousandth of a degree over does.
    assert np.isclose(tolerance_rate(np.array([5.0000001, 5.001, 4.0])), 200 / 3)


def test_errors_per_degree_of_freedom_follow_the_camera_path():
    # Camera path points -> labels; the errors must read back the path differences.
    R, t = camera_poses([10, 350, 0], [20, 30, 40], [0, 0, 0], [0.6, 0.7, 0.8])
    R2, t2 = camera_poses([20, 170, 0], [25, 30, 40], [0, 0, 3], [0.6, 0.75, 0.8])
    e = pose_errors(pose_to_label(R2, t2), pose_to_label(R, t))
    assert np.allclose(e["azimuth"], [10, 180, 0]) and np.allclose(e["azimuth_mod180"], [10, 0, 0])
    assert np.allclose(e["elevation"], [5, 0, 0]) and np.allclose(e["roll"], [0, 0, 3], atol=1e-9)
    assert np.allclose(e["distance"], [0, 0.05, 0])
    s = summarise(e)
    assert np.isclose(s["median_error"]["azimuth_deg"], 10) and np.isclose(s["median_error"]["distance_mm"], 0)
    assert np.isclose(s["median_error"]["azimuth_mod180_deg"], 0)


def test_accuracy_curve_and_its_normalised_area():
    geodesic = np.array([0.0, 10.0, 30.0, np.nan])        # the NaN frame (no estimate) is a miss
    curve = accuracy_curve(geodesic, 4, thresholds=np.array([0.0, 10.0, 20.0, 30.0, 40.0]))
    assert np.allclose(curve, [25, 50, 50, 75, 75])
    # Trapezoids over [0, 40]: (37.5 + 50 + 62.5 + 75) * 10 / 40 = 56.25.
    assert np.isclose(curve_auc(curve, thresholds=np.array([0.0, 10.0, 20.0, 30.0, 40.0])), 56.25)
    perfect = summarise(pose_errors(np.array([[90.0, 0, 0, 0, 0, 1]]), np.array([[90.0, 0, 0, 0, 0, 1]])))
    assert np.isclose(perfect["auc_45"], 100.0) and perfect["geodesic_median_deg"] < 1e-5


def test_the_other_euler_triple_of_a_rotation_and_unmeasured_nans_are_not_errors():
    true = np.array([[30.0, 20, 10, 0, 0, 0.7]])
    other = np.array([[30.0 - 180, 180 - 20, 10 - 180, 0, 0, 0.7]])      # the same rotation
    e = pose_errors(other, true)
    assert np.isclose(e["rotation_max"][0], 0, atol=1e-9) and e["geodesic"][0] < 1e-9
    measured = np.array([[False, False, True, False, False, False]])      # azimuth only, as COIL-100
    partial = pose_errors(np.array([[np.nan, np.nan, 12.0, np.nan, np.nan, np.nan]]), np.array([[0, 0, 10.0, 0, 0, 1]]),
                          measured)
    assert partial["rotation_max"][0] == 2.0 and summarise(partial)["success_tol5"] == 100.0
    same = pose_errors(np.array([[91.0, 3, -47, 0, 0, 1]]), np.array([[91.0, 3, -47, 0, 0, 1]]))
    assert same["geodesic"][0] < 1e-9                   # far below the 1e-6 of float noise the criteria allow

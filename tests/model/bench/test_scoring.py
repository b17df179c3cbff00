"""spm_model.bench.scoring: success against occlusion in tenths, and per-class eccentricity."""

import numpy as np

from spm_model.bench.feature_cache import FeatureTable
from spm_model.bench.scoring import eccentricity, occlusion_rows


def test_occlusion_rows_count_each_tenth_and_score_it():
    occ = np.array([0.0, 0.05, 0.15, 0.95, 1.0])
    errors = {"rotation_max": np.array([1.0, 10.0, 2.0, np.inf, 4.0]),
              "rotation_sum": np.array([2.0, 20.0, 4.0, np.inf, 6.0]),
              "geodesic": np.array([1.0, 9.0, 2.0, np.nan, 4.0]),
              "translation": np.array([0.001, 0.002, 0.003, np.nan, 0.004])}
    rows = occlusion_rows(occ, errors)
    assert len(rows) == 10 and [r["frames"] for r in rows] == [2, 1, 0, 0, 0, 0, 0, 0, 0, 2]
    assert rows[0]["success_tol5"] == 50.0 and rows[0]["success_sum5"] == 50.0 and rows[0]["success_sum3"] == 50.0
    assert rows[0]["geodesic_median_deg"] == 5.0 and np.isclose(rows[0]["translation_median_mm"], 1.5)
    assert rows[1]["success_sum3"] == 0.0 and rows[2]["success_tol5"] is None
    assert rows[9]["success_tol5"] == 50.0 and rows[9]["geodesic_median_deg"] == 4.0   # 1.0 is in the last bin


def test_eccentricity_per_class_leaves_out_frames_without_an_ellipse():
    table = FeatureTable({"class_name": np.array(["a", "a", "b"]), "query_eccentricity": np.array([0.2, np.nan, 0.5]),
                          "pose": np.zeros((3, 6))})
    assert eccentricity(table) == {"a": {"mean": 0.2, "std": 0.0, "frames": 1},
                                   "b": {"mean": 0.5, "std": 0.0, "frames": 1}}

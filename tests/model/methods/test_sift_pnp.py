"""SiftPnPPose (SIFT + PnP over all matches; N3M's fallback on its own): poses of views off the
training grid, N3M's fallback poses reproduced, SIFT shared with N3M, the estimator contract."""

import numpy as np
import pytest

from spm_model.errors import ModelError
from spm_model.base.estimator import Needs
from spm_model.methods.n3m import N3MPose
from spm_model.methods.sift_pnp import SiftPnPPose
from tests.helpers import grid_split, within_5_degrees


@pytest.fixture(scope="module")
def fitted(model_shards):
    """(SiftPnPPose, N3MPose with the fallback, the split) fitted on model_shards' 10-degree grid."""
    train, poses, test, truth = grid_split(model_shards)
    return (SiftPnPPose().fit(train, poses), N3MPose(ransac_fallback=True).fit(train, poses),
            (train, poses, test, truth))


def test_recovers_the_poses_of_views_off_the_training_grid(fitted):
    model, _, (_, _, test, truth) = fitted
    pred, sources = model.predict_details(test)
    assert pred.shape == (len(test), 6) and set(sources) <= {"ransac", None}
    assert within_5_degrees(pred, truth).mean() >= 0.9, within_5_degrees(pred, truth).mean()
    found = np.all(np.isfinite(pred), axis=1)
    assert np.median(np.linalg.norm(pred[found, 3:] - truth[found, 3:], axis=1)) < 0.006   # metres, at 128 px
    assert np.array_equal(model.features_found(test), np.ones(len(test), bool))
    blank = {"rgb": np.zeros((128, 128, 3), np.uint8), "mask": np.ones((128, 128), bool), "K": test[0]["K"]}
    assert np.all(np.isnan(model.predict([blank]))) and not model.features_found([blank])[0]


def test_same_points_as_n3m_and_its_fallback_poses_exactly(fitted):
    """No markers: N3M's database and matching, and where N3M's markers fail and its fallback
    poses the frame, that very pose (one RANSAC, fixed seed)."""
    model, n3m, (_, _, test, _) = fitted
    for name in ("points_", "point_object_", "descriptors_", "descriptor_point_", "merge_radius_"):
        np.testing.assert_array_equal(getattr(model, name), getattr(n3m, name))
    assert not hasattr(model, "markers_") and not hasattr(model, "quality_")
    pred, _ = model.predict_details(test)
    pred_n3m, sources = n3m.predict_details(test)
    fallback = [i for i, s in enumerate(sources) if s == "ransac"]
    assert len(fallback) >= 1
    np.testing.assert_array_equal(pred[fallback], pred_n3m[fallback])


def test_shares_n3ms_sift_memo(fitted, monkeypatch):
    """Run after N3M (same sift_side and max_keypoints), SIFT + PnP extracts no SIFT of its own."""
    from spm_model.base import feature_memo
    from spm_model.base.feature_memo import clear_memo, memo_stats

    _, _, (train, poses, test, _) = fitted
    train, poses, test = train[:30], poses[:30], test[:8]
    monkeypatch.setenv("SPM_FEATURE_MEMO_MB", "64")
    # In memory only: an on-disk memo an earlier test of this process opened would turn the
    # first extraction's misses into disk hits.
    monkeypatch.setattr(feature_memo, "_folder", [None])
    clear_memo()
    N3MPose().fit(train, poses).predict(test)
    misses = memo_stats()["misses"]
    assert misses == len(train) + len(test)
    SiftPnPPose().fit(train, poses).predict(test)
    assert memo_stats()["misses"] == misses and memo_stats()["hits"] >= len(train) + len(test)
    clear_memo()


def test_the_contract_needs_and_parameters():
    assert SiftPnPPose.NEEDS == N3MPose.NEEDS == Needs(frames=2, depth=True)
    assert SiftPnPPose.DETERMINISTIC is True
    model = SiftPnPPose(sift_side=128, min_inliers=8)
    assert model.get_params() == {"sift_side": 128, "max_keypoints": 300, "max_train_frames": 1500,
                                  "merge_pixels": 1.5, "descriptors_per_point": 6, "ratio": 0.8,
                                  "reprojection_error": 3.0, "min_inliers": 8}
    shared = {k: v for k, v in N3MPose().get_params().items() if k in model.get_params()}
    assert shared == SiftPnPPose().get_params()                         # the same defaults: one SIFT memo
    assert repr(model).startswith("SiftPnPPose(sift_side=128")


def test_errors_name_the_estimator():
    frame = {"rgb": np.zeros((32, 32, 3), np.uint8), "mask": np.ones((32, 32), bool), "K": np.eye(3)}
    with pytest.raises(ModelError, match="this SiftPnPPose is not fitted yet"):
        SiftPnPPose().predict([frame])
    with pytest.raises(ModelError, match=r"SiftPnPPose.fit: poses must be \(n, 6\)"):
        SiftPnPPose().fit([frame], np.zeros((1, 5)))
    with pytest.raises(ModelError, match="SiftPnPPose: training frame 0 has no depth"):
        SiftPnPPose().fit([frame], np.zeros((1, 6)))
    depth_frame = {**frame, "depth": np.full((32, 32), 0.5, np.float32)}
    with pytest.raises(ModelError, match="SiftPnPPose: SIFT found no keypoint"):
        SiftPnPPose().fit([depth_frame], np.array([[0, 0, 0, 0, 0, 0.5]]))

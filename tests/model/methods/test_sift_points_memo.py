"""spm_model.methods.sift_points_memo: N3M and SIFT + PnP with the same parameters merge their points,
build their index and search each test image once a process, with results identical to computing
each anew; other parameters or another training set are other entries."""

import numpy as np
import pytest

from spm_model.base import feature_memo
from spm_model.methods import sift_points_memo as memo
from spm_model.methods.n3m import N3MPose
from spm_model.methods.sift_pnp import SiftPnPPose
from tests.helpers import grid_split


@pytest.fixture
def small_split(model_shards, monkeypatch):
    monkeypatch.setattr(feature_memo, "_folder", [None])   # in memory only, whatever an earlier test opened
    train, poses, test, _ = grid_split(model_shards)
    memo.clear_memo()                                      # whatever earlier tests of this process left
    yield train[:30], poses[:30], test[:8]
    memo.clear_memo()


def _fit_predict(train, poses, test, **params):
    n3m, pnp = N3MPose(**params).fit(train, poses), SiftPnPPose(**params).fit(train, poses)
    return n3m, pnp, n3m.predict(test), pnp.predict(test)


def test_the_second_method_is_served_and_its_estimates_are_the_same(small_split, monkeypatch):
    train, poses, test = small_split
    monkeypatch.setenv("SPM_FEATURE_MEMO_MB", "0")
    alone = _fit_predict(train, poses, test)
    assert memo.memo_stats() == {"hits": 0, "misses": 0, "points": 0, "indexes": 0, "neighbours": 0}
    monkeypatch.setenv("SPM_FEATURE_MEMO_MB", "64")
    shared = _fit_predict(train, poses, test)
    stats = memo.memo_stats()
    # points: one miss (N3M), one hit (SIFT + PnP); index the same; each test image searched once
    assert (stats["points"], stats["indexes"], stats["neighbours"]) == (1, 1, len(test))
    assert stats["hits"] == 1 + 1 + len(test) and stats["misses"] == 1 + 1 + len(test)
    for a, b in zip(alone, shared):
        if isinstance(a, np.ndarray):
            np.testing.assert_array_equal(a, b)
    for name in SiftPnPPose.FITTED:
        np.testing.assert_array_equal(getattr(alone[0], name), getattr(shared[1], name))
    with pytest.raises(ValueError):
        shared[1].points_[0, 0] = 1.0                                    # shared between the two: read-only


def test_other_parameters_or_frames_are_other_entries(small_split, monkeypatch):
    train, poses, test = small_split
    monkeypatch.setenv("SPM_FEATURE_MEMO_MB", "64")
    SiftPnPPose().fit(train, poses)
    SiftPnPPose(merge_pixels=3.0).fit(train, poses)
    SiftPnPPose().fit(train[:20], poses[:20])
    assert memo.memo_stats()["points"] == 2 and memo.memo_stats()["hits"] == 0   # two kept, the oldest forgotten
    SiftPnPPose(merge_pixels=3.0).fit(train, poses)
    assert memo.memo_stats()["hits"] == 1

"""spm_model.spm.bunches: EM finds known clusters of keypoints, seeded; too few keypoints are refused."""

import numpy as np
import pytest

from spm_model.spm.bunches import BunchError, fit_bunches


def test_em_recovers_known_clusters():
    rng = np.random.default_rng(3)
    true = np.array([[20, 20], [60, 25], [100, 20], [20, 70], [60, 65], [100, 75], [35, 110], [90, 110.0]])
    pts = np.concatenate([m + rng.normal(0, 3.0, (25, 2)) for m in true])
    b = fit_bunches(pts, gamma=8, seed=1)
    assert b.means.shape == (8, 2) and b.weights.sum() == pytest.approx(1.0)
    error = np.min(np.linalg.norm(b.means[:, None] - true[None], axis=2), axis=0)  # each true centre found
    assert error.max() < 2.0
    again = fit_bunches(pts, gamma=8, seed=1)
    np.testing.assert_array_equal(again.means, b.means)  # seeded: repeatable


def test_too_few_keypoints_are_refused():
    with pytest.raises(BunchError, match="15 keypoints is too few for 8 clusters"):
        fit_bunches(np.random.default_rng(0).random((15, 2)))

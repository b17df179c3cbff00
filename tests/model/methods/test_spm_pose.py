"""spm_model.methods.spm_pose: SPM needs features on ten frames and gives NaN without one."""

import numpy as np
import pytest

from spm_model.errors import ModelError
from spm_model.methods.spm_pose import SPMNeighbours, SPMPose
from tests.helpers import FAST_SPM, N, frames, labels


def test_spm_pose_needs_features_on_ten_frames_and_gives_nan_without_one():
    f, poses = frames(N, 0), labels(N, 0)
    vectors = f.columns["train_vector"].copy()
    vectors[3:] = np.nan                                 # only 3 frames with a feature
    few = type(f)({**f.columns, "train_vector": vectors})
    with pytest.raises(ModelError, match=r"^only 3 training frames have SPM features \(need 10\)"):
        SPMPose(params=FAST_SPM).fit(few, poses)
    model = SPMPose(params=FAST_SPM).fit(f, poses)
    query = f.columns["query_vector"].copy()
    query[[1, 4]] = np.nan
    pred = model.predict(type(f)({**f.columns, "query_vector": query}))
    assert np.isnan(pred[[1, 4]]).all() and np.isfinite(np.delete(pred, [1, 4], axis=0)).all()
    knn = SPMNeighbours(k=1, spm=model).fit(f, poses)
    assert knn.spm_ is model                              # an SPM fitted already is reused, not refitted

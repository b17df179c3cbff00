"""spm_model.commands.predict: the region of interest must lie inside the image; what is
printed for results and failures."""

import pytest

from spm_data.errors import ModelError
from spm_model.commands.predict import format_predictions, prediction_errors, roi_mask


def test_roi_mask_is_the_box_and_refuses_one_outside_the_image():
    mask = roi_mask((2, 1, 3, 2), width=6, height=4)
    assert mask.shape == (4, 6) and mask.sum() == 6 and mask[1:3, 2:5].all()
    with pytest.raises(ModelError, match=r"reaches outside the image \(x \+ width = 7"):
        roi_mask((4, 0, 3, 2), width=6, height=4)
    with pytest.raises(ModelError, match="is empty"):
        roi_mask((0, 0, 0, 2), width=6, height=4)


def test_predictions_print_one_line_per_pose_and_one_per_failure():
    results = [{"image": "a.png", "pose": dict(zip(("rx", "ry", "rz", "tx", "ty", "tz"), (1, 2, 3, 0.1, 0.2, 0.3))),
                "keypoints": 40, "eccentricity": 0.5},
               {"image": "b.png", "error": "no such file"}]
    assert format_predictions(results, as_json=False) == \
        "a.png: rx 1.0 ry 2.0 rz 3.0 deg, t (0.100, 0.200, 0.300) m  [40 keypoints]"
    assert prediction_errors(results) == ["b.png: no such file"]
    assert '"error": "no such file"' in format_predictions(results, as_json=True)

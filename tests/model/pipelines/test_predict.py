"""spm_model.pipelines.predict: the region of interest must lie inside the image; what is
printed for results and failures."""

import pytest

from spm_model.errors import ModelError
from spm_model.pipelines.predict import format_predictions, prediction_errors, roi_mask


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


def test_predict_counts_every_image_read_or_failed(tmp_path, monkeypatch):
    import numpy as np
    from PIL import Image

    import spm_model.pipelines.predict as predict

    class Model:
        def predict_image(self, rgb, mask):
            return {"pose": np.zeros(6)}

    class Steps:
        def phase(self, label, total, unit):
            self.step = [label, total, unit, 0]

        def __call__(self, n):
            self.step[3] += n

    Image.fromarray(np.zeros((8, 8, 3), np.uint8)).save(tmp_path / "a.png")
    monkeypatch.setattr(predict, "load_model", lambda path, device=None: Model())
    progress = Steps()
    results = predict.predict_images("model.npz", [tmp_path / "a.png", tmp_path / "missing.png"], progress=progress)
    assert [("error" in r) for r in results] == [False, True] and progress.step == ["predict", 2, "image", 2]

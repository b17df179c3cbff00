"""benchmarks/predict_rate.py: the region of interest it predicts with (--roi object: each image's
object box widened by 10% a side, inside the image; or a fixed box), as spm predict --roi gives it."""

import importlib.util
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]


def _script():
    spec = importlib.util.spec_from_file_location("predict_rate", ROOT / "benchmarks" / "predict_rate.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_object_box_is_the_masks_widened_and_kept_inside_the_image():
    rate = _script()
    mask = np.zeros((48, 64), np.uint8)
    mask[10:30, 20:60] = 1                                   # 40 x 20 pixels
    assert rate.object_box(mask) == (16, 8, 48, 24)          # 4 and 2 pixels a side, clipped at x = 64
    assert rate.object_box(np.zeros((48, 64), np.uint8)) == (0, 0, 64, 48)
    assert (rate.parse_roi(None), rate.parse_roi("object"), rate.parse_roi("1,2,30,40")) == (None, "object",
                                                                                          (1, 2, 30, 40))


def test_timing_passes_each_images_roi_to_the_model_as_a_mask():
    rate = _script()
    seen = []

    class Model:
        def predict_image(self, rgb, mask=None):
            seen.append(None if mask is None else (int(mask.sum()), mask.shape))
            return {"pose": np.zeros(6)}

    imgs = [np.zeros((48, 64, 3), np.uint8)] * 2
    times, poses, cpu = rate.time_model(Model(), imgs, 2, rois=[(0, 0, 10, 5), (4, 4, 2, 3)])
    assert len(times) == 4 and len(poses) == 2 and cpu >= 0
    assert seen == [(50, (48, 64)), (6, (48, 64))] * 3        # the warm-up and two passes

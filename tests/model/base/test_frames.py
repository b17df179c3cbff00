"""spm_model.base.frames: what an estimator gets (images, masks, K and cached features, never labels),
and the documented example estimator (docs/estimators.md) run on it."""

import numpy as np

from spm_model.bench.feature_cache import load_features
from spm_model.spm.features import FeatureConfig

FAST = FeatureConfig(ellipse="direct")


def test_the_documented_example_estimator_runs(model_shards):
    from pathlib import Path

    from spm_model.base.frames import Frames

    text = (Path(__file__).resolve().parents[3] / "docs" / "estimators.md").read_text()
    code = text.split("```python\n", 1)[1].split("```", 1)[0]
    namespace = {}
    exec(compile(code, "docs/estimators.md", "exec"), namespace)
    table = load_features(model_shards, FAST)
    train, test = np.flatnonzero(table.class_name != "cup"), np.flatnonzero(table.class_name == "cup")
    model = namespace["BoxSize"]().fit(Frames(table, train), table.pose[train])
    pred = model.predict(list(Frames(table, test)))                  # a plain list of frame dicts works too
    assert pred.shape == (48, 6)
    assert np.median(np.abs(np.linalg.norm(pred[:, 3:], axis=1) - 0.6)) < 0.01   # every frame of this set is at 0.6 m


def test_frames_serve_features_never_labels(model_shards):
    from spm_model.base.frames import Frames

    table = load_features(model_shards, FAST)
    frames = Frames(table, np.arange(5))
    assert frames.column("template").shape[0] == 5 and frames.column("K").shape == (5, 3, 3)
    for label in ("pose", "class_name", "instance", "instance_id", "label_measured"):
        assert frames.column(label) is None, label
    assert set(frames[0]) == {"rgb", "mask", "K"} and not hasattr(frames, "table")

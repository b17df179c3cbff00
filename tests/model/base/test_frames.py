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


def test_training_frames_serve_images_depth_and_paths_never_labels(model_shards):
    from spm_data.io.shards import read_shard
    from spm_model.base.frames import TRAIN_KEYS, Frames

    table = load_features(model_shards, FAST)
    frames = Frames(table, np.arange(40, 45))
    assert frames.column("template").shape[0] == 5 and frames.column("K").shape == (5, 3, 3)
    for label in ("pose", "class_name", "instance", "instance_id", "label_measured", "train_vector_x"):
        assert frames.column(label) is None, label
    assert tuple(frames[0]) == TRAIN_KEYS and not hasattr(frames, "table") and not hasattr(frames, "_table")
    stored = read_shard(table.shard[42], ("rgb", "mask", "depth"), frames=slice(int(table.frame[42]),
                                                                                  int(table.frame[42]) + 1))
    f = frames[2]
    assert np.array_equal(f["rgb"], stored["rgb"][0]) and np.array_equal(f["mask"], stored["mask"][0] > 0)
    assert np.array_equal(f["depth"], stored["depth"][0]) and f["depth"].dtype == np.float32
    assert f["path_index"] == int(table.path_index[42]) and frames[-1]["sequence"] == f["sequence"]
    assert len(frames[1:3]) == 2 and frames[1:3][0]["path_index"] == frames[1]["path_index"]


def test_camera_frames_hold_what_a_camera_sees_in_the_order_asked(model_shards):
    from spm_model.base.frames import CAMERA_KEYS, Frames, read_camera_frames

    table = load_features(model_shards, FAST)
    rows = np.array([100, 3, 57])
    cam = read_camera_frames(table, rows)
    train = Frames(table, rows)
    assert len(cam) == 3 and tuple(cam[1]) == CAMERA_KEYS
    for i in range(3):
        assert np.array_equal(cam[i]["rgb"], train[i]["rgb"]) and np.array_equal(cam[i]["mask"], train[i]["mask"])
    assert np.array_equal(cam.column("template"), table.template[rows]) and cam.column("train_vector") is None
    assert cam.column("pose") is None and len(cam[::2]) == 2 and np.array_equal(cam[::2][1]["K"], table.K[57])


def test_asking_whether_a_frame_has_a_key_reads_nothing(model_shards, monkeypatch):
    from spm_model.base.frames import Frames

    table = load_features(model_shards, FAST)
    frames = Frames(table, np.arange(3))
    reads = []
    monkeypatch.setattr(Frames, "_value", lambda self, i, key: reads.append(key))
    assert "rgb" in frames[0] and "depth" in frames[0] and "pose" not in frames[0] and "label" not in frames[1]
    assert reads == []
    frames[0]["mask"]
    assert reads == ["mask"]

import numpy as np
import pytest

from spm_data.core.poses import label_to_pose
from spm_data.io.shards import list_shards, read_shard
from spm_model.spm.estimator import ModelError
from spm_model.methods.descriptors import box_of, template_descriptor
from spm_model.methods.template import TemplatePose


@pytest.fixture(scope="module")
def frames(instance_shards):
    """Plain frame dicts (no cached columns) and their poses."""
    data = [read_shard(p, ["rgb", "mask", "K", "pose"]) for p in list_shards(instance_shards)]
    d = {k: np.concatenate([x[k] for x in data]) for k in data[0]}
    return [{"rgb": d["rgb"][i], "mask": d["mask"][i] > 0, "K": d["K"][i]} for i in range(len(d["pose"]))], d["pose"]


def test_each_training_frame_finds_itself_and_the_model_file_round_trips(frames, tmp_path):
    f, poses = frames
    model = TemplatePose(components=32)
    assert model.fit(f, poses) is model and model.basis_.shape[1] == 32
    pred = model.predict(f)
    R, t = label_to_pose(pred)
    R0, t0 = label_to_pose(poses)
    assert np.allclose(R, R0, atol=1e-9)                                  # its own template, exactly
    assert np.median(np.linalg.norm(t - t0, axis=1)) < 1e-3               # distance from apparent size
    path = model.save(tmp_path / "ref.npz")
    loaded = TemplatePose.load(path)
    assert loaded.components == 32 and np.array_equal(loaded.predict(f), pred)
    with pytest.raises(ModelError, match=r"^this TemplatePose is not fitted yet; call fit\(frames, poses\) first, "
                                         r"or load a model file with TemplatePose\.load\(path\)$"):
        TemplatePose().predict(f)
    from spm_model.base.model_files import save_model_file

    save_model_file(tmp_path / "other.npz", "spm", {}, {"W": np.zeros(2)})
    with pytest.raises(ModelError, match="of kind spm is not one this spm reads here"):
        TemplatePose.load(tmp_path / "other.npz")


def test_a_shifted_object_keeps_its_rotation_and_moves_its_translation(frames):
    f, poses = frames
    model = TemplatePose(components=32).fit(f, poses)
    i, shift = 5, 12                                                       # 12 pixels to the right
    moved = {"rgb": np.roll(f[i]["rgb"], shift, axis=1), "mask": np.roll(f[i]["mask"], shift, axis=1), "K": f[i]["K"]}
    base, shifted = model.predict([f[i]])[0], model.predict([moved])[0]
    assert np.allclose(base[:3], shifted[:3])                              # rotation: the same template
    fx = f[i]["K"][0, 0]
    assert np.isclose(shifted[3] / shifted[5] - base[3] / base[5], shift / fx, atol=1e-9)
    corrected = TemplatePose(components=32, ray_correction=True).fit(f, poses).predict([moved])[0]
    R_base, _ = label_to_pose(base)
    R_corr, _ = label_to_pose(corrected)
    turn = np.degrees(np.arccos(np.clip((np.trace(R_corr @ R_base.T) - 1) / 2, -1, 1)))
    ray = np.array([base[3] / base[5] + shift / fx, base[4] / base[5], 1.0])
    want = np.degrees(np.arccos(np.clip(ray[2] / np.linalg.norm(ray), -1, 1)))
    assert np.isclose(turn, want, atol=1e-6)                               # turned by the ray's angle off axis


def test_descriptor_of_an_empty_mask_is_nan_and_gives_no_estimate(frames):
    f, poses = frames
    empty = {"rgb": f[0]["rgb"], "mask": np.zeros_like(f[0]["mask"]), "K": f[0]["K"]}
    assert box_of(empty["mask"]) is None and np.isnan(template_descriptor(**empty)).all()
    model = TemplatePose(components=8).fit(f[:20], poses[:20])
    assert np.isnan(model.predict([empty])).all()
    out = model.predict_image(f[3]["rgb"], f[3]["mask"])
    assert out["pose"].shape == (6,) and np.isfinite(out["pose"]).all()


def test_the_size_window_never_reuses_a_frame_at_the_ends_of_the_sizes():
    model = TemplatePose(size_neighbours=3)
    sizes = np.array([10.0, 11, 12, 13, 14, 15, 16, 17])           # apparent sizes, focal 1
    model.geometry_ = np.column_stack([np.zeros(8), np.zeros(8), sizes, np.ones(8), np.zeros((8, 3))])
    model.distance_ = np.array([0.90, 0.80, 0.70, 0.65, 0.60, 0.55, 0.50, 0.45])
    query = np.column_stack([np.zeros(3), np.zeros(3), [5.0, 13.4, 30.0], np.ones(3), np.zeros((3, 3))])
    # Smaller than every frame: the 3 smallest (0.9, 0.8, 0.7), not the smallest three times;
    # in the middle: 13, 14, 12; larger than every frame: the 3 largest.
    np.testing.assert_allclose(model._distance(query), [0.80, 0.65, 0.50])
    model.size_neighbours = 15                                      # more neighbours than frames: all of them
    np.testing.assert_allclose(model._distance(query), np.median(model.distance_))

import json
import sys

import numpy as np
import pytest

from spm_model.errors import ModelError
from spm_model.base.safetensors_file import read_safetensors
from spm_model.bench.metrics import wilson_interval
from spm_model.methods.baselines import ChancePose
from spm_model.methods.cnn import CNNPose, device_note, soft_targets, view_bins, rotation_quaternions
from tests.helpers import CachedFrames, grid_split, within_5_degrees

# A budget for tests: seconds on one thread (the default trains 500 steps of 64 frames).
SMALL = {"steps": 150, "epochs": 100, "batch": 32, "width": 8, "embed": 32, "threads": 1, "device": "cpu"}


@pytest.fixture(scope="module")
def split(model_shards):
    """Training frames on a 10-degree grid (3 classes, 72 frames) and test frames 5 degrees off them (24)."""
    return grid_split(model_shards)


@pytest.fixture(scope="module")
def fitted(split):
    train, poses, test, truth = split
    return CNNPose(**SMALL).fit(train, poses)


def test_it_learns_poses_far_above_chance(split, fitted):
    train, poses, test, truth = split
    hit = within_5_degrees(fitted.predict(test), truth)
    chance = within_5_degrees(ChancePose(seed=0).fit(train, poses).predict(test), truth)
    low, _ = wilson_interval(100 * hit.mean(), len(hit))
    _, high = wilson_interval(100 * chance.mean(), len(chance))
    assert low > high, (hit.mean(), chance.mean())               # the 95% intervals do not overlap
    assert fitted.training_["steps"] == 150 and fitted.training_["device"] == "cpu"
    assert fitted.training_["frames"] == 72 and fitted.training_["seconds"] > 0


def test_two_fits_with_one_seed_give_the_same_predictions(split, fitted):
    train, poses, test, truth = split
    again = CNNPose(**SMALL).fit(train, poses)
    assert all(np.array_equal(again.net_[k], fitted.net_[k]) for k in fitted.net_)
    assert np.array_equal(again.predict(test), fitted.predict(test))


def test_a_fit_reads_the_cached_template_hogs_and_codes_them_as_it_would_compute_them(split, fitted, monkeypatch):
    from spm_model.methods import cnn
    from spm_model.methods.descriptors import hog_descriptor, template_descriptor

    train, poses, test, truth = split
    # Two frames the fit leaves out, among the others: an empty mask (its cached row is NaN) and no pose.
    frames = list(train[:10]) + [{**train[0], "mask": np.zeros_like(train[0]["mask"])}, train[1]] + list(train[10:])
    labels = np.concatenate([poses[:10], poses[:1], np.full((1, 6), np.nan), poses[10:]])
    hog = hog_descriptor()
    template = np.stack([template_descriptor(f["rgb"], f["mask"], f["K"], hog) for f in frames])
    assert np.isnan(template[10]).all() and np.isfinite(template[11]).all()

    def no_computing(crops):
        raise AssertionError("the HOG was computed although the frames carry it")

    with monkeypatch.context() as patched:
        patched.setattr(cnn, "crop_hogs", no_computing)
        cached = CNNPose(**SMALL).fit(CachedFrames({"template": template}, frames), labels)
    assert np.array_equal(cached.hog_codes_, fitted.hog_codes_) and np.array_equal(cached.hog_axes_, fitted.hog_axes_)
    assert all(np.array_equal(cached.net_[k], fitted.net_[k]) for k in fitted.net_)
    template[3, 5] = np.nan   # a damaged cached row: the HOG is computed instead, and comes out the same
    again = CNNPose(**SMALL).fit(CachedFrames({"template": template}, frames), labels)
    assert np.array_equal(again.hog_codes_, fitted.hog_codes_)


def test_a_pickled_model_travels_without_its_torch_module_and_predicts_the_same(split, fitted):
    import pickle

    train, poses, test, truth = split
    payload = pickle.dumps(fitted)
    again = pickle.loads(payload)
    assert "_module" not in again.__dict__ and b"torch" not in payload
    assert np.array_equal(again.predict(test), fitted.predict(test))


def test_the_model_file_round_trips_and_its_safetensors_hold_the_same_weights(split, fitted, tmp_path):
    from spm_model.pipelines.evaluate import load_model

    train, poses, test, truth = split
    path = fitted.save(tmp_path / "cnn-model.npz")
    loaded = load_model(path)                                     # as spm evaluate and spm predict load it
    # The device is where it runs now (--device; default auto), not the one it trained on.
    assert isinstance(loaded, CNNPose) and loaded.get_params() == {**fitted.get_params(), "device": "auto"}
    assert load_model(path, "cpu").device == "cpu"
    assert np.array_equal(loaded.predict(test), fitted.predict(test))
    assert loaded.training_ == json.loads(json.dumps(fitted.training_))
    arrays, metadata = read_safetensors(path.with_suffix(".safetensors"))
    assert json.loads(metadata["params"])["steps"] == 150
    for name, value in fitted.net_.items():
        assert np.array_equal(arrays[f"net.{name}"], value) and arrays[f"net.{name}"].dtype == value.dtype
    assert np.array_equal(arrays["embeddings"], fitted.embeddings_)
    for name in ("hog_mean", "hog_axes", "hog_codes"):                # the HOG codes' state, both files
        assert np.array_equal(arrays[name], getattr(fitted, name + "_"))
        assert np.array_equal(getattr(loaded, name + "_"), getattr(fitted, name + "_"))
    assert fitted.hog_codes_.shape == (72, fitted.hog_axes_.shape[1]) and fitted.hog_codes_.dtype == np.float32
    one = loaded.predict_image(test[0]["rgb"], test[0]["mask"], test[0]["K"])["pose"]
    assert np.allclose(one, fitted.predict(test[:1])[0])


def test_an_empty_mask_gives_no_estimate_and_an_unfitted_model_one_error(split, fitted):
    train, poses, test, truth = split
    blank = {**test[0], "mask": np.zeros_like(test[0]["mask"])}
    out = fitted.predict([blank, test[1]])
    assert np.isnan(out[0]).all() and np.isfinite(out[1]).all()
    with pytest.raises(ModelError, match=r"^this CNNPose is not fitted yet; call fit\(frames, poses\) first, "
                                         r"or load a model file with CNNPose\.load\(path\)$"):
        CNNPose().predict(test)


def test_without_torch_fit_and_load_fail_with_one_line_naming_the_extra(split, fitted, monkeypatch, tmp_path):
    from spm_model.pipelines.evaluate import load_model

    train, poses, test, truth = split
    path = fitted.save(tmp_path / "cnn-model.npz")
    monkeypatch.setitem(sys.modules, "torch", None)                # import torch raises ImportError
    for call in (lambda: CNNPose(**SMALL).fit(train, poses), lambda: load_model(path)):
        with pytest.raises(ModelError) as caught:
            call()
        assert str(caught.value) == ("the cnn method needs PyTorch, which is not installed here; "
                                     "pip install 'spm[learn]' (make install includes it)")


def test_device_note_says_where_the_cnn_runs_and_nothing_without_torch_on_auto(monkeypatch):
    import torch

    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    assert device_note("auto") == "cnn device: cpu (auto: torch sees no GPU here, so the CPU)"
    assert device_note("cpu") == "cnn device: cpu"
    monkeypatch.setitem(sys.modules, "torch", None)                # import torch raises ImportError
    assert device_note("auto") is None                               # the method is declined, the others run
    with pytest.raises(ModelError, match="^the cnn method needs PyTorch"):
        device_note("cpu")                                           # asked for by name: one line, before any work


def test_view_bins_spread_over_the_rotations_and_targets_favour_the_nearest():
    labels = np.zeros((36, 6))
    labels[:, 2] = np.arange(0, 360, 10)                          # one turn, 10 degrees apart
    labels[:, 5] = 1.0
    q = rotation_quaternions(labels)
    assert sorted(view_bins(q, 100)) == list(range(36))           # fewer poses than bins: one bin each
    four = view_bins(q, 4)
    angles = np.sort(labels[four, 2])
    assert len(four) == 4 and np.allclose(np.diff(angles), 90, atol=10)   # spread round the turn
    t = soft_targets(q, q)
    assert np.allclose(t.sum(axis=1), 1) and (np.argmax(t, axis=1) == np.arange(36)).all()
    assert np.isclose(t[0, 1], t[0, 35]) and t[0, 1] < t[0, 0] / 5  # neighbours alike, well below the pose


def test_spm_train_writes_the_cnn_model_with_its_cost_and_spm_predict_runs_it(model_shards, tmp_path):
    from PIL import Image

    from spm_data.io.shards import list_shards, read_shard
    from spm_model.pipelines.predict import predict_images
    from spm_model.pipelines.train import train
    from spm_model.spm.features import FeatureConfig

    result = train(model_shards, tmp_path / "report", protocol="views", runs=1,
                   features=FeatureConfig(ellipse="direct"), builtins=["cnn", "chance"])
    assert result["models"] == {"cnn": "written"}
    assert result["model_files"] == {"cnn": tmp_path / "report" / "cnn-model.npz"}
    assert (tmp_path / "report" / "cnn-model.safetensors").is_file()
    payload = json.loads((tmp_path / "report" / "results.json").read_text())
    cost = payload["context"]["training"]["cnn"]
    assert cost["frames"] == 144 and cost["steps"] == 90 and cost["device"] in ("cpu", "cuda")  # 40 epochs of 144
    assert f"The CNN trained in {cost['seconds']:.1f} s (90 steps, 40 epochs of 144 frames" in \
        (tmp_path / "report" / "results.md").read_text()
    assert "cnn" in payload["summary"]["methods"]
    frame = read_shard(list_shards(model_shards)[0], ("rgb", "mask"), frames=slice(0, 1))
    Image.fromarray(frame["rgb"][0]).save(tmp_path / "view.png")
    Image.fromarray((frame["mask"][0] > 0).astype(np.uint8) * 255).save(tmp_path / "mask.png")
    out = predict_images(result["model_files"]["cnn"], [tmp_path / "view.png"], mask_path=tmp_path / "mask.png")
    assert "error" not in out[0] and np.isfinite(list(out[0]["pose"].values())).all()


def test_augmentation_hides_part_of_the_object_and_recuts_the_crop_to_what_is_seen():
    from spm_model.methods.cnn import augmented, frame_crop, net_input

    rgb = np.zeros((96, 128, 3), np.uint8)
    rgb[20:70, 30:90] = 180                                          # a bright 60 x 50 object
    mask = rgb[..., 0] > 0
    crop, geometry = frame_crop(rgb, mask, np.array([[100.0, 0, 63.5], [0, 100.0, 47.5], [0, 0, 1]]))
    assert np.allclose(geometry[:3], (59.5, 44.5, 60.0))              # box centre and longer side, pixels
    plain = net_input(crop, 32)
    rng = np.random.default_rng(0)
    draws = [augmented(crop, 32, 0.6, rng) for _ in range(40)]
    assert all(d.shape == (2, 32, 32) and d.dtype == np.float32 and 0 <= d.min() <= d.max() <= 1 for d in draws)
    seen = np.array([(d[1] > 0.5).mean() for d in draws])
    hidden = np.array([((d[1] > 0.5) & (d[0] == 0)).sum() for d in draws])
    assert (hidden == 0).all()                                        # hidden pixels leave the mask too
    # A crop whose left half is hidden is re-cut to the box of its right half (as a test frame's visible
    # mask cuts it): what is seen spans the input's long side (32 px less the 5% margins)...
    half = crop.copy()
    half[:, :, :32] = 0
    recut = net_input(half, 32)[1] > 0.5
    assert max(np.ptp(np.flatnonzero(recut.any(axis=k))) for k in (0, 1)) >= 27          # 50 px of the half: 29
    assert np.ptp(np.flatnonzero(recut.any(axis=0))) < np.ptp(np.flatnonzero(recut.any(axis=1)))  # 30 x 50 px
    # ...and some draws lose part of it (about half are occluded), others keep it whole.
    whole = (plain[1] > 0.5).mean()
    assert (seen < whole - 0.02).sum() >= 5 and np.isclose(seen, whole, atol=0.02).sum() >= 5
    clean = [augmented(crop, 32, 0.0, rng) for _ in range(5)]         # no occlusion: only the jitter
    assert all(np.array_equal(d[1], plain[1]) for d in clean)


def _state(model, **changed) -> dict:
    return {**model.get_params(), **{k: getattr(model, k) for k in CNNPose.FITTED}, **changed}


def test_hog_re_ranking_picks_the_neighbour_whose_appearance_matches(split, fitted):
    """A training view queried as itself, its embedding moved a hair away and its 10-degree neighbour's
    put exactly on the query's: the embedding alone retrieves the neighbour, the HOG re-ranking the view."""
    from spm_model.methods.cnn import angles_to

    train, poses, test, truth = split
    q = rotation_quaternions(poses)
    same = np.array([f["sequence"] == train[0]["sequence"] for f in train])          # frame 0's object
    gap = np.where(same, angles_to(q, q[:1])[:, 0], np.inf)
    gap[0] = np.inf
    j = int(np.argmin(gap))                                               # the nearest other view of frame 0
    assert 5 < np.degrees(gap[j]) < 15
    z = fitted.embeddings_[0].copy()
    moved = fitted.embeddings_.copy()
    moved[j] = z
    moved[0] = (z + 0.02 * np.roll(z, 1)) / np.linalg.norm(z + 0.02 * np.roll(z, 1))   # cosine 0.9998 to z
    plain = CNNPose.from_state(**_state(fitted, embeddings_=moved, rerank=0))
    reranked = CNNPose.from_state(**_state(fitted, embeddings_=moved))
    assert reranked.rerank == -1 and reranked.hog_weight == 16.0                      # the defaults
    assert np.allclose(plain.predict(train[:1])[0, :3], poses[j, :3])                   # the neighbour
    assert np.allclose(reranked.predict(train[:1])[0, :3], poses[0, :3])                # the view itself


def test_rerank_0_keeps_the_nearest_embedding_and_the_same_network(split, fitted):
    """rerank 0: no HOG state, the same training (re-ranking is after the network), and each query's
    pose that of its nearest training embedding."""
    from spm_model.methods.cnn import cnn_net, frame_crops, net_input

    train, poses, test, truth = split
    plain = CNNPose(**SMALL, rerank=0).fit(train, poses)
    assert all(np.array_equal(plain.net_[k], fitted.net_[k]) for k in fitted.net_)
    assert plain.hog_codes_.shape == (72, 0) and plain.hog_mean_.size == plain.hog_axes_.size == 0
    crops, _ = frame_crops(test)
    import torch

    z = cnn_net.embed_all(torch, plain._net(torch), np.stack([net_input(c, plain.side) for c in crops]), "cpu")
    nearest = np.argmax(z @ plain.embeddings_.T, axis=1)
    assert np.allclose(plain.predict(test)[:, :3], poses[nearest, :3])
    plain.check_loaded()                                                   # empty HOG arrays are fine then


@pytest.mark.parametrize("rerank", [-2, 2.5, -1.5])
def test_a_rerank_that_names_no_retrieval_is_one_line(split, rerank):
    train, poses, test, truth = split
    with pytest.raises(ModelError, match=r"^CNNPose rerank must be -1 \(every training frame\), 0 or 1"):
        CNNPose(**SMALL, rerank=rerank).fit(train, poses)


def test_a_model_file_saved_with_the_16_nearest_re_ranking_keeps_it(split, fitted, tmp_path):
    """A file written when the default was the 16 nearest embeddings re-ranked with weight 2 loads with
    them, and retrieves exactly as nearest_frames does with that shortlist."""
    from spm_model.methods.cnn import cnn_net, frame_crops, net_input
    from spm_model.methods.cnn_retrieval import crop_hogs, nearest_frames
    from spm_model.methods.template import project_hog
    from spm_model.pipelines.evaluate import load_model

    train, poses, test, truth = split
    old = CNNPose.from_state(**_state(fitted, rerank=16, hog_weight=2.0))
    loaded = load_model(old.save(tmp_path / "cnn-model.npz"))
    assert (loaded.rerank, loaded.hog_weight) == (16, 2.0)
    crops, _ = frame_crops(test)
    import torch

    z = cnn_net.embed_all(torch, loaded._net(torch), np.stack([net_input(c, loaded.side) for c in crops]), "cpu")
    codes = project_hog(crop_hogs(crops), loaded.hog_mean_, loaded.hog_axes_, np.float32)
    picked = nearest_frames(z, loaded.embeddings_, codes, loaded.hog_codes_, 2.0, 16)
    assert np.allclose(loaded.predict(test)[:, :3], poses[picked, :3])
    assert np.array_equal(loaded.predict(test), old.predict(test))


@pytest.mark.parametrize("rerank", [-5, 2.5, "all"])
def test_check_loaded_rejects_a_rerank_that_names_no_retrieval(fitted, rerank):
    with pytest.raises(ValueError, match=r"^rerank is .*: -1 \(every training frame\)"):
        CNNPose.from_state(**_state(fitted, rerank=rerank)).check_loaded()


def test_check_loaded_rejects_hog_arrays_that_do_not_fit(fitted):
    codes, axes = fitted.hog_codes_, fitted.hog_axes_
    for bad in ({"hog_codes_": codes[:-1]}, {"hog_codes_": codes[:, :-1]}, {"hog_axes_": axes[:-1]},
                {"hog_mean_": fitted.hog_mean_[:5]}, {"hog_codes_": np.zeros((72, 0), np.float32)}):
        with pytest.raises(ValueError, match="^HOG code arrays of shapes"):
            CNNPose.from_state(**_state(fitted, **bad)).check_loaded()
    broken = codes.copy()
    broken[3, 1] = np.nan
    with pytest.raises(ValueError):
        CNNPose.from_state(**_state(fitted, hog_codes_=broken)).check_loaded()
    CNNPose.from_state(**_state(fitted)).check_loaded()                      # as fitted: fine


def test_re_ranking_in_blocks_of_queries_picks_as_one_query_at_a_time(split, fitted):
    """1,200 queries (past two 512-query blocks) pick exactly what each picks alone."""
    from spm_model.methods.cnn import frame_crops

    train, poses, test, truth = split
    crops, _ = frame_crops(test + train)
    crops = np.concatenate([crops] * 13)[:1200]
    rng = np.random.default_rng(0)
    z = rng.normal(size=(1200, fitted.embed)).astype(np.float32)
    z /= np.linalg.norm(z, axis=1, keepdims=True)
    together = fitted.nearest(z, crops)
    alone = np.array([fitted.nearest(z[i: i + 1], crops[i: i + 1])[0] for i in range(0, 1200, 7)])
    assert np.array_equal(together[::7], alone)
    assert (together != np.argmax(z @ fitted.embeddings_.T, axis=1)).any()    # the re-ranking did act


def test_a_model_file_saved_before_the_re_ranking_loads_as_the_nearest_embedding(split, fitted, tmp_path):
    import copy

    from spm_model.base.model_files import save_model_file
    from spm_model.pipelines.evaluate import load_model

    train, poses, test, truth = split
    before = {k: v for k, v in fitted.get_params().items() if k not in ("rerank", "hog_weight", "hog_components")}
    arrays = {**{f"net/{k}": v for k, v in fitted.net_.items()},
              **{k[:-1]: getattr(fitted, k) for k in CNNPose.FITTED if k != "net_" and not k.startswith("hog_")}}
    path = save_model_file(tmp_path / "cnn-model.npz", "cnn", before, arrays, {"training": None})
    loaded = load_model(path)
    nearest = copy.copy(fitted)
    nearest.rerank = 0
    assert loaded.rerank == 0 and loaded.hog_codes_.shape == (len(fitted.poses_), 0)
    assert np.array_equal(loaded.predict(test), nearest.predict(test))

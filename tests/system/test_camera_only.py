"""Methods see only what a camera sees: a plug-in that searches the test frames for labels
finds nothing, gets the visible mask (never the full silhouette) on occluded copies, and
gets the test frames in a seeded random order."""

import hashlib
import pickle
import shutil
import textwrap

import numpy as np

from spm_data.pipelines.occlude_jobs import occlude_dataset
from spm_data.io.shards import read_shard
from spm_model.bench.feature_cache import load_features
from spm_model.bench.protocols import evaluate
from spm_model.spm.features import FeatureConfig

FAST = FeatureConfig(ellipse="direct")

SPY = '''
import pathlib
import pickle

import numpy as np


def reachable(obj, seen=None, depth=0):
    """Everything reachable from obj through attributes, slots, mappings and sequences."""
    seen = set() if seen is None else seen
    if id(obj) in seen or depth > 6:
        return
    seen.add(id(obj))
    yield obj
    if isinstance(obj, (str, bytes, int, float, np.ndarray)):
        return
    children = []
    if isinstance(obj, dict):
        children += list(obj.keys()) + list(obj.values())
    elif isinstance(obj, (list, tuple, set)):
        children += list(obj)[:64]
    for name in dir(obj):
        if name.startswith("__"):
            continue
        try:
            value = getattr(obj, name)
        except Exception:
            continue
        if not callable(value):
            children.append(value)
    for child in children:
        yield from reachable(child, seen, depth + 1)


class Spy:
    """Notes what each predict could reach, one pickle per call in found/ beside this module (it
    runs in a process of its own)."""

    def fit(self, frames, poses):
        self.mean_ = np.asarray(poses).mean(axis=0)
        return self

    def predict(self, frames):
        items = list(reachable(frames)) + [x for i in range(min(len(frames), 8)) for x in reachable(frames[i])]
        found = {
            "strings": [x for x in items if isinstance(x, str)],
            "arrays": [x for x in items if isinstance(x, np.ndarray) and x.dtype.kind == "f"],
            "keys": sorted({k for i in range(len(frames)) for k in frames[i]}),
            "order": [frames[i]["rgb"].tobytes() for i in range(len(frames))],
            "masks": [frames[i]["mask"] for i in range(len(frames))],
        }
        folder = pathlib.Path(__file__).with_name("found")
        folder.mkdir(exist_ok=True)
        (folder / f"{len(list(folder.iterdir())):04d}.pkl").write_bytes(pickle.dumps(found))
        return np.tile(self.mean_, (len(frames), 1))
'''


class _Found(list):
    """What the Spy noted, in order (read from its found/ folder by ``load``)."""

    def __init__(self, folder):
        super().__init__()
        self.folder = folder

    def load(self):
        self[:] = [pickle.loads(p.read_bytes()) for p in sorted(self.folder.glob("*.pkl"))]
        return self

    def clear(self):
        shutil.rmtree(self.folder, ignore_errors=True)
        super().clear()


def _spy(tmp_path, monkeypatch):
    (tmp_path / "spy_pose.py").write_text(textwrap.dedent(SPY))
    monkeypatch.syspath_prepend(str(tmp_path))
    import importlib
    import sys

    sys.modules.pop("spy_pose", None)   # this test's module, not an earlier test's
    spy_pose = importlib.import_module("spy_pose")
    spy_pose.Spy.found = _Found(tmp_path / "found")
    return spy_pose.Spy


def test_a_plugin_looking_for_labels_finds_nothing_and_gets_a_seeded_random_order(model_shards, tmp_path,
                                                                                 monkeypatch):
    spy = _spy(tmp_path, monkeypatch)
    table = load_features(model_shards, FAST)
    params = {"features": FAST}
    evaluate(table, "loco", runs=1, model_params=params, estimators={"Spy": spy}, builtins=["chance"])
    assert len(spy.found.load()) == 3                                            # one predict per tested class
    for (tested, found), cls in zip(enumerate(spy.found), ("box", "car", "cup")):
        test = np.flatnonzero(table.class_name == cls)
        assert found["keys"] == ["K", "mask", "rgb"]
        text = " ".join(found["strings"])
        for secret in ("box", "car", "cup", ".h5", str(model_shards), "pose", "instance"):
            assert secret not in text, (secret, text[:200])
        poses = table.pose[test]
        for arr in found["arrays"]:
            flat = np.asarray(arr, np.float64).ravel()
            for width, part in ((6, poses), (3, poses[:, 3:])):   # a label row, or a translation
                if flat.size % width == 0:
                    rows = flat.reshape(-1, width)
                    assert not np.isclose(rows[:, None, :], part[None, :, :], atol=1e-6).all(-1).any(), arr.shape
        # The order is not the table's (camera-path) order, and it is the same with the same seed.
        stored = read_shard(table.shard[test[0]], ("rgb",))["rgb"]
        path_order = [stored[int(f)].tobytes() for f in table.frame[test]]
        assert sorted(found["order"]) == sorted(path_order) and found["order"] != path_order
    first = [hashlib.sha256(b"".join(f["order"])).hexdigest() for f in spy.found]
    spy.found.clear()
    evaluate(table, "loco", runs=1, model_params=params, estimators={"Spy": spy}, builtins=["chance"])
    assert [hashlib.sha256(b"".join(f["order"])).hexdigest() for f in spy.found.load()] == first


def test_occluded_copies_hand_the_visible_mask_and_train_clean_under_offgrid(model_shards, tmp_path, monkeypatch):
    shutil.copytree(model_shards, tmp_path / "clean")
    occlude_dataset(tmp_path / "clean", tmp_path / "occluded", low=0.3, high=0.6, copies=1, seed=4)
    spy = _spy(tmp_path, monkeypatch)
    from spm_model.bench.feature_cache import offgrid_table

    table = offgrid_table(load_features(tmp_path / "clean", FAST), load_features(tmp_path / "occluded", FAST))
    evaluation = evaluate(table, "offgrid", runs=1, model_params={"features": FAST}, estimators={"Spy": spy},
                          builtins=["chance"])
    assert evaluation["train_occluded"] is False
    masks = [m for f in spy.found.load() for m in f["masks"]]
    test = np.flatnonzero(table.test)
    full = sum(int(read_shard(s, ("mask",))["mask"].astype(bool).sum()) for s in sorted(set(table.shard[test])))
    visible = sum(int(read_shard(s, ("visible_mask",))["visible_mask"].astype(bool).sum())
                  for s in sorted(set(table.shard[test])))
    assert sum(int(m.sum()) for m in masks) == visible < 0.8 * full   # never the amodal silhouette
    fig5 = evaluation["runs"][0]["fig5"]
    assert set(fig5) == {"all", "seen"} and set(fig5["seen"]) == {"all", "rectangles"}
    rows = fig5["seen"]["rectangles"]["Spy"]
    assert sum(r["frames"] for r in rows) == len(test) and rows[0]["frames"] == 0   # every copy is 30-60% hidden

"""spm_model.bench.fitting: each method fitted and asked alone; what it needs checked first; one that
cannot run (needs unmet, fit or predict raising, a wrong output) declined with its reason while
the others are scored; the frames each method found its features on."""

import numpy as np
import pytest

from spm_model.base.estimator import Needs
from spm_model.bench.feature_cache import FeatureTable, load_features
from spm_model.bench.fitting import failure, fit_predict, unmet_needs
from spm_model.spm.features import FeatureConfig

FAST = FeatureConfig(ellipse="direct")


def table(n=12, depth=True, featured=12, paths=2):
    vectors = np.full((n, 16), np.nan)
    vectors[:featured] = 1.0
    return FeatureTable({"has_depth": np.full(n, depth), "train_vector": vectors,
                         "shard": np.array([f"s{i % paths}.h5" for i in range(n)]), "instance_id": np.zeros(n, int)})


class Plain:
    pass


class Deep(Plain):
    NEEDS = Needs(depth=True, frames=4)

    def fit(self, frames, poses):
        return self

    def predict(self, frames):
        return np.full((len(frames), 6), np.nan)


class Pairs:
    NEEDS = Needs(sequences=2, spm_features=10)


def test_unmet_needs_name_what_the_training_frames_lack():
    rows = np.arange(12)
    assert unmet_needs(Plain(), table(), rows) is None and unmet_needs(Deep, table(), rows) is None
    assert unmet_needs(Deep, table(), rows[:3]) == "needs 4 training frames or more, got 3"
    assert unmet_needs(Deep, table(depth=False), rows).startswith("needs depth: none of the 12 training frames has")
    assert unmet_needs(Pairs, table(paths=1), rows) == ("needs 2 camera paths (sequences) among the training frames, "
                                                        "got 1")
    assert unmet_needs(Pairs, table(featured=9), rows).startswith("needs 10 training frames with SPM features, 9 of "
                                                                  "12 have them")
    assert unmet_needs(Pairs, table(featured=9), rows[:9]).startswith("needs 10 training frames with SPM features")


def test_needs_are_checked_when_declared():
    with pytest.raises(Exception, match="must be a whole number >= 0"):
        Needs(frames=-1)

    class Wrong:
        NEEDS = {"depth": True}

    from spm_model.errors import ModelError

    with pytest.raises(ModelError, match=r"Wrong.NEEDS must be a spm_model.base.estimator.Needs, got dict"):
        unmet_needs(Wrong, table(), np.arange(3))


def test_failure_is_one_line_with_the_type_of_what_was_not_ours():
    from spm_model.errors import ModelError

    assert failure(ModelError("only 3 training frames\n have features")) == "only 3 training frames have features"
    assert failure(ZeroDivisionError("division by zero"), "predict: ") == "predict: ZeroDivisionError: division by zero"


class Raises:
    def fit(self, frames, poses):
        raise RuntimeError("my bug")

    def predict(self, frames):
        raise AssertionError("never called")


class BreaksLater:
    def fit(self, frames, poses):
        self.n_ = 0
        return self

    def predict(self, frames):
        self.n_ += 1
        if self.n_ > 1:
            raise ValueError("second chunk")
        return np.zeros((len(frames), 6))


class Fussy:
    def __init__(self):
        raise ValueError("needs a licence file")


class Counts:
    def fit(self, frames, poses):
        self.mean_ = np.asarray(poses).mean(axis=0)
        return self

    def predict(self, frames):
        return np.tile(self.mean_, (len(frames), 1))

    def features_found(self, frames):
        return np.arange(len(frames)) % 2 == 0


def test_one_method_failing_never_takes_the_others_down(model_shards, monkeypatch):
    import spm_model.bench.fitting as fitting

    t = load_features(model_shards, FAST)
    train, test = np.flatnonzero(t.class_name != "box"), np.flatnonzero(t.class_name == "box")
    monkeypatch.setattr(fitting, "camera_chunks", lambda tab, rows: [rows[:20], rows[20:]])   # two chunks
    plugins = {"raises": Raises, "later": BreaksLater, "counts": Counts, "deep": Deep, "fussy": Fussy}
    predictions, declined, found = fit_predict((0, {"features": FAST}, [], plugins), t, train, test)
    assert list(predictions) == ["counts", "deep"] and predictions["counts"].shape == (48, 6)
    assert declined == {"raises": "RuntimeError: my bug", "later": "predict: ValueError: second chunk",
                        "fussy": "Fussy(): ValueError: needs a licence file"}   # its constructor raised
    assert found["deep"] is None and found["counts"].shape == (48,)
    assert found["counts"].sum() == 10 + 14             # every other frame of each chunk of 20 and 28
    t.arrays["has_depth"] = np.zeros(len(t), bool)
    _, declined, _ = fit_predict((0, {"features": FAST}, [], {"deep": Deep}), t, train, test)
    assert declined["deep"].startswith("needs depth")


def test_a_later_run_takes_only_the_reused_methods_notes_from_the_first():
    """smm declined in run 1 but ran in run 2; pca (deterministic) is reused from run 1."""
    from spm_model.bench.protocols import _with_first_run

    test = np.arange(4)
    errors = {"rotation_max": np.zeros(4)}
    first = ("all", 10, test, {"pca": errors, "smm": errors},
             {"declined": {"smm": "no pairs"}, "featured": {"pca": None, "smm": 0}})
    later = ("all", 10, test, {"smm": errors}, {"declined": {}, "featured": {"smm": 3}})
    _, _, _, merged, notes = _with_first_run(later, first)
    assert list(merged) == ["pca", "smm"] and notes == {"declined": {}, "featured": {"pca": None, "smm": 3}}

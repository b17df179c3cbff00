"""spm_model.pipelines.check_estimator: a plug-in run through the estimator contract on the built-in
set, one line a check; a plug-in that breaks it fails the named checks, exit status 1."""

import numpy as np
import pytest
from click.testing import CliRunner

from cli import model_cli
from spm_model.pipelines.check_estimator import built_in_set, failed, run_checks
from tests.model.bench.test_isolation import MemoCheat, OrderCheat, StackCheat


@pytest.fixture(scope="module")
def check_set(tmp_path_factory):
    return built_in_set(tmp_path_factory.mktemp("check") / "set")


class Good:
    DETERMINISTIC = True

    def __init__(self, *, shift=0.0):
        self.shift = shift

    def get_params(self):
        return {"shift": self.shift}

    def fit(self, frames, poses):
        self.mean_ = np.asarray(poses).mean(axis=0) + self.shift
        return self

    def predict(self, frames):
        if not hasattr(self, "mean_"):
            raise RuntimeError("not fitted")
        return np.tile(self.mean_, (len(frames), 1))

    def features_found(self, frames):
        return np.ones(len(frames), bool)


class Batchy(Good):
    """Promises DETERMINISTIC, yet a frame's label depends on the batch, and no error before fit."""

    def __init__(self, *, shift=1.0):
        self.shift = 2 * shift            # not stored as given

    def predict(self, frames):
        return np.tile([float(len(frames))] * 6, (len(frames), 1))


class Needy(Good):
    def __init__(self, size):
        self.size = size


def _checks(cls, table, timeout=60.0):
    lines = []
    done = run_checks(cls, table, lines.append, timeout)
    return done, lines


class ReadsTheFiles(Good):
    """Gets the test labels some other way than the images: it opens the shard files its training
    frames are read from, and looks each test image up there."""
    DETERMINISTIC = False

    def fit(self, frames, poses):
        from spm_data.io.shards import read_shard

        self.files_ = sorted({str(s) for s in frames._shard})
        self.read_ = read_shard
        return super().fit(frames, poses)

    def predict(self, frames):
        """The label of the stored frame whose image equals each test image (a lookup in the files)."""
        out = np.full((len(frames), 6), np.nan)
        stored = {}
        for path in self.files_:
            d = self.read_(path, ("rgb", "pose"))
            stored.update({d["rgb"][i].tobytes(): d["pose"][i] for i in range(len(d["rgb"]))})
        for i in range(len(frames)):
            out[i] = stored.get(frames[i]["rgb"].tobytes(), out[i])
        return out


class Exits(Good):
    def fit(self, frames, poses):
        raise SystemExit(0)


class Sleeps(Good):
    def fit(self, frames, poses):
        import threading

        threading.Event().wait()   # blocks until its process is ended (never a fixed time)


def test_a_plug_in_that_keeps_the_contract_passes_every_check(check_set):
    done, lines = _checks(Good, check_set)
    assert failed(done) == [] and [c.status for c in done].count("ok") == 14
    assert lines[-2].startswith("note  on this set: 48 of 48 test frames estimated, ") and "(chance " in lines[-2]
    assert lines[-1].startswith("ok    trained on poses permuted against the images, it scores as chance does")


@pytest.mark.parametrize("cheat", [StackCheat, MemoCheat, OrderCheat])
def test_cheats_score_as_chance_does_in_the_checks_own_run(check_set, cheat):
    done, lines = _checks(cheat, check_set)
    score = next(c.text for c in done if c.text.startswith("on this set"))
    low = float(score.split("[")[1].split("–")[0])
    chance_high = float(score.split("chance ")[1].split("–")[1].split("]")[0])
    assert low <= chance_high, score
    assert not [c for c in failed(done) if c.text.startswith("trained on poses permuted")], lines


def test_a_plug_in_that_finds_labels_in_the_files_fails_the_permuted_images_check(check_set):
    done, lines = _checks(ReadsTheFiles, check_set)
    bad = [c.text for c in failed(done)]
    assert len(bad) == 1 and bad[0].startswith("trained on poses permuted against the images, it scores as chance "
                                               "does (100.0% "), lines


def test_a_plug_in_that_ends_its_process_or_runs_too_long_fails_and_the_list_ends(check_set):
    done, _ = _checks(Exits, check_set)
    assert [c.line() for c in failed(done)] == [
        "FAIL  fit(frames, poses) on 48 frames: it raised SystemExit (exit code 0); a method cannot end the run"]
    # 10 s: importing this test module in the method's process counts (plug-in code), busy machines too
    done, _ = _checks(Sleeps, check_set, timeout=10.0)
    assert [c.line() for c in failed(done)] == ["FAIL  fit: took longer than the time limit (--timeout 10 s)"]


def test_each_broken_promise_is_a_failed_check_naming_the_fix(check_set):
    done, _ = _checks(Batchy, check_set)
    bad = {c.text.split(":")[0] for c in failed(done)}
    assert bad == {"__init__ stores its parameters as given (get_params round trip)", "predict before fit raises",
                   "a frame's label does not depend on the frames predicted with it"}
    done, _ = _checks(Needy, check_set)
    assert [c.line() for c in failed(done)] == [
        "FAIL  constructs with no arguments: TypeError: Needy.__init__() missing 1 required positional argument: "
        "'size'; give every parameter a default"]


def test_the_command_prints_one_line_a_check_and_exits_1_on_a_failure(plugin_module):
    r = CliRunner().invoke(model_cli, ["check-estimator", "my_pose:MeanPose"])
    assert r.exit_code == 0, r.output
    assert r.output.splitlines()[-1] == "15 checks, 0 failed; my_pose:MeanPose can run in spm train"
    r = CliRunner().invoke(model_cli, ["check-estimator", "my_pose:WrongShape"])
    assert r.exit_code == 1
    assert "FAIL  predict(frames) returns (48, 6) labels: estimator WrongShape: predict(frames) must return (48, 6)" \
        in r.output and "FAIL  predict before fit raises" in r.output and r.output.endswith("8 checks, 2 failed\n")
    r = CliRunner().invoke(model_cli, ["check-estimator", "my_pose"])
    assert (r.exit_code, r.output) == (1, "error: --estimator expects MODULE:CLASS (for example my_pose:MyEstimator), "
                                          "got 'my_pose'\n")


def _builtin_classes():
    from spm_model.bench.fitting import builtin_classes
    from spm_model.spm.features import FeatureConfig

    return builtin_classes({"features": FeatureConfig()})


@pytest.mark.parametrize("name", list(_builtin_classes()))
def test_every_built_in_method_passes_the_checks_a_plug_in_must(check_set, name):
    """scikit-learn's parametrize_with_checks habit: the built-in methods meet the contract they set."""
    done, lines = _checks(_builtin_classes()[name], check_set)
    assert failed(done) == [], lines
    assert any(c.text.startswith("on this set: ") for c in done) and lines[-1].startswith("ok    trained on poses")

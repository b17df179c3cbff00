"""spm_model.commands.check_estimator: a plug-in run through the estimator contract on the built-in
set, one line a check; a plug-in that breaks it fails the named checks, exit status 1."""

import numpy as np
import pytest
from click.testing import CliRunner

from cli import model_cli
from spm_model.commands.check_estimator import _Checks, _run, built_in_set, failed


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


def _checks(cls, table):
    checks = _Checks(cls, table)
    lines = []
    _run(checks, lines.append)
    return checks.done, lines


def test_a_plug_in_that_keeps_the_contract_passes_every_check(check_set):
    done, lines = _checks(Good, check_set)
    assert failed(done) == [] and [c.status for c in done].count("ok") == 13
    assert lines[-1].startswith("note  on this set: 48 of 48 test frames estimated")


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
    assert r.output.splitlines()[-1] == "14 checks, 0 failed; my_pose:MeanPose can run in spm train"
    r = CliRunner().invoke(model_cli, ["check-estimator", "my_pose:WrongShape"])
    assert r.exit_code == 1
    assert "FAIL  predict(frames) returns (48, 6) labels: estimator WrongShape: predict(frames) must return (48, 6)" \
        in r.output and "FAIL  predict before fit raises" in r.output and r.output.endswith("8 checks, 2 failed\n")
    r = CliRunner().invoke(model_cli, ["check-estimator", "my_pose"])
    assert (r.exit_code, r.output) == (1, "error: --estimator expects MODULE:CLASS (for example my_pose:MyEstimator), "
                                          "got 'my_pose'\n")

"""spm_model.pipelines.check_contract: each check of check-estimator is one message to the parent;
a plug-in that returns the wrong thing, or raises SystemExit, fails its check and the child goes
on (it never ends the process that runs the checks)."""

import io
import json
from multiprocessing import Pipe

import numpy as np

from spm_model.pipelines.check_contract import ContractChecks
from tests.model.pipelines.test_check_estimator import Good as Mean   # a plug-in keeping the contract

POSES = np.arange(24, dtype=np.float64).reshape(4, 6)
FRAMES = np.zeros((4, 1))   # the checks only count and index frames; the plug-ins below ignore them
CAMERA = np.zeros((3, 1))


class ReturnsNone(Mean):
    def fit(self, frames, poses):
        super().fit(frames, poses)


class Exits(Mean):
    def fit(self, frames, poses):
        raise SystemExit(0)


def _run(cls) -> list:
    read, write = Pipe(duplex=False)
    checks = ContractChecks(write, cls, FRAMES, POSES, CAMERA)
    model = checks.construct()
    checks.params(model)
    checks.unfitted()
    model = checks.fit(model)
    if model is not None:
        out = checks.predictions(model)
        checks.repeat(model, out)
    out = []
    while read.poll(0):
        header = json.loads(read.recv_bytes())
        [np.load(io.BytesIO(read.recv_bytes()), allow_pickle=False) for _ in range(header["arrays"])]
        if header["kind"] == "check":
            out.append((header["status"], header["text"]))
    return out


def test_a_plug_in_keeping_the_contract_passes_every_check():
    lines = _run(Mean)
    assert [s for s, _ in lines if s == "FAIL"] == []
    texts = [t for _, t in lines]
    assert "fit returns self" in texts and "predict before fit raises" in texts
    assert "predict(frames) returns (3, 6) labels" in texts


def test_fit_that_does_not_return_self_fails_that_check_and_stops_the_rest():
    lines = _run(ReturnsNone)
    assert ("FAIL", "fit returns self: it returned NoneType; end fit with `return self`") in lines
    assert not any("predict(frames)" in t for _, t in lines)


def test_system_exit_in_fit_is_a_failed_check_not_the_end_of_the_process():
    lines = _run(Exits)
    [(status, text)] = [(s, t) for s, t in lines if t.startswith("fit(frames, poses)")]
    assert status == "FAIL" and "SystemExit (exit code 0)" in text

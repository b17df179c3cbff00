"""benchmarks/isolation_cost.py (issue 46): the in-process stand-in runs the child's own code in a
thread and gives the same results.json as isolation; a run writes its figures and loads; a
difference between the two ways is named."""

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from tests.helpers import load_script

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def cost():
    return load_script("benchmarks/isolation_cost.py", "isolation_cost")


def test_the_stand_in_is_in_place_for_the_job_only(cost):
    from spm_model.bench import fitting
    from spm_model.bench.isolation import fresh_process

    assert cost.with_stand_in(lambda job, report: (fitting.fresh_process, job), "job", None) == (cost.ThreadChild,
                                                                                              "job")
    assert fitting.fresh_process is fresh_process
    with pytest.raises(KeyError):
        cost.with_stand_in(lambda job, report: {}[job], "boom", None)
    assert fitting.fresh_process is fresh_process


class MeanPose:
    """The mean training pose for every frame."""

    def fit(self, frames, poses):
        self.mean_ = poses.mean(axis=0)
        return self

    def predict(self, frames):
        return np.tile(self.mean_, (len(frames), 1))


def test_the_thread_child_fits_and_predicts_over_the_pipe_and_ends_when_closed(cost):
    from spm_model.spm.features import FeatureConfig

    child = cost.ThreadChild()
    poses = np.arange(12.0).reshape(2, 6)
    child.send(("start", (0, {"features": FeatureConfig()}, {"mean": MeanPose}), ["mean"], ["a", "b"], poses, None))
    assert child.reply("mean", "fit: ", None)[0]["why"] is None
    child.send(["c", "d", "e"])
    header, arrays = child.reply("mean", "predict: ", None)
    assert header["why"] is None and np.array_equal(arrays[0], np.tile([3.0, 4, 5, 6, 7, 8], (3, 1)))
    child.close()
    assert child.proc.poll() == 0 and not child.proc.is_alive()


def _results(folder: Path, figure: float) -> None:
    (folder / "loco").mkdir(parents=True)
    (folder / "loco" / "results.json").write_text(json.dumps(
        {"summary": {"methods": {"knn1": {"success_tol5": figure, "frames": 10}}}}))


def test_a_difference_between_two_runs_is_named(cost, tmp_path):
    _results(tmp_path / "a", 0.25)
    _results(tmp_path / "b", 0.25)
    _results(tmp_path / "c", 0.5)
    assert cost.first_difference(tmp_path / "a", tmp_path / "b") is None
    assert cost.first_difference(tmp_path / "a", tmp_path / "c") == (
        f"loco knn1: success_tol5 differs by 0.25 between {tmp_path / 'a'} and {tmp_path / 'c'}")
    shutil.rmtree(tmp_path / "c" / "loco")
    assert cost.first_difference(tmp_path / "a", tmp_path / "c") == f"loco: in {tmp_path / 'a'} but not in " \
                                                                     f"{tmp_path / 'c'}"


def test_figures_are_medians_and_their_ratio(cost):
    runs = {("isolated", 1): {"loco": {"wall_s": 11.0}}, ("in-process", 1): {"loco": {"wall_s": 10.0}},
            ("isolated", 2): {"loco": {"wall_s": 13.0}}, ("in-process", 2): {"loco": {"wall_s": 10.0}}}
    found = cost.figures(runs, ["loco"])
    assert found["loco"] == {"isolated_s": [11.0, 13.0], "in_process_s": [10.0, 10.0], "isolated_median_s": 12.0,
                             "in_process_median_s": 10.0, "ratio": 1.2}
    assert found["total"] == found["loco"]


def test_one_worker_is_refused_in_one_line(tmp_path):
    r = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "isolation_cost.py"), str(tmp_path), "--out",
                        str(tmp_path / "o"), "--workers", "1"], capture_output=True, text=True, timeout=300)
    assert r.returncode == 2 and r.stderr.splitlines()[-1].startswith("isolation_cost.py: error: --workers must "
                                                                      "be 2 or more"), r.stderr


def test_both_ways_give_the_same_results_and_the_figures_are_written(model_shards, tmp_path):
    shards = tmp_path / "shards"
    shutil.copytree(model_shards, shards)
    measure = tmp_path / "isolation-cost.json"
    r = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "isolation_cost.py"), str(shards), "--out",
                        str(tmp_path / "out"), "--protocols", "loco", "--runs", "1", "--methods", "knn1,template",
                        "--rounds", "1", "--order", "in-process-first", "--measure", str(measure)],
                       capture_output=True, text=True, timeout=900,
                       env={**os.environ, "SPM_PROGRESS_EVERY": "100000"})
    assert r.returncode == 0, r.stderr[-3000:]
    assert "results.json summaries identical in all 2 runs" in r.stdout
    for way in ("isolated-1", "in-process-1"):
        assert (tmp_path / "out" / way / "loco" / "results.json").is_file()
    snap = json.loads(measure.read_text())
    loco = snap["summary"]["protocols"]["loco"]
    assert snap["summary"]["total"] == loco
    assert len(loco["isolated_s"]) == len(loco["in_process_s"]) == 1 and loco["isolated_s"][0] > 0
    assert loco["ratio"] == round(loco["isolated_median_s"] / loco["in_process_median_s"], 3)
    assert snap["summary"]["frames"] == 144 and snap["summary"]["identical"] is True
    made = snap["made"]
    assert made["command"].startswith("python benchmarks/isolation_cost.py ") and "--rounds 1" in made["command"]
    assert [(x["way"], x["protocol"]) for x in made["loads"]] == [("in-process", "loco"), ("isolated", "loco")]
    assert made["parameters"]["methods"] == "knn1,template" and made["machine"]["nproc"] == os.cpu_count()
    results_doc = load_script("scripts/results_doc.py", "results_doc")
    table = results_doc.table_isolation_cost(snap)   # what a doc's measure-table block shows
    assert f"| loco | {loco['isolated_s'][0]:.1f} | {loco['in_process_s'][0]:.1f} |" in table
    assert "| total |" in table and f"| {loco['ratio']:.3f} |" in table and made["command"] in table

"""spm_model/bench/jobs.py: the benchmark's jobs are frozen values a worker can be sent."""

import dataclasses
import pickle

import pytest

from spm_model.bench.jobs import FinalJob, SplitJob


def test_a_split_job_names_its_fields_and_survives_pickling():
    job = SplitJob(("shards", None), "loco", 1, 2, {"gamma": 8}, ["knn1"], None, True, 30.0)
    assert (job.run, job.index, job.protocol, job.builtins) == (1, 2, "loco", ["knn1"])
    assert pickle.loads(pickle.dumps(job)) == job


def test_jobs_are_frozen():
    job = FinalJob("source", {}, False, ("spm", "template"))
    with pytest.raises(dataclasses.FrozenInstanceError):
        job.wanted = ()
    assert job != SplitJob("source", "loco", 0, 0, {}, None, None, False, None)

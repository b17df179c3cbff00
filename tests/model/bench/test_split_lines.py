"""spm_model/bench/split_lines.py: a split's line waits for the lines of the jobs before it, and
names the declines the summary counts, those reused from run 1 marked."""

import numpy as np

from spm_model.bench.jobs import FinalJob, SplitJob
from spm_model.bench.split_lines import SplitLines, split_line


def _job(run, split):
    return SplitJob("source", "loco", run, split, {}, None, None, True, None)


def _output(tested, ran, declined, frames=3):
    """A split_job output: ``ran`` the methods fitted in it, ``declined`` those of them that declined."""
    return (tested, 10, np.arange(frames), {m: {} for m in ran},
            {"declined": {m: "why" for m in declined}, "featured": {m: None for m in ran}})


def test_lines_come_in_job_order_whatever_order_the_jobs_end_in():
    jobs = [FinalJob("source", {}, True, ("spm",))] + [_job(r, s) for r in (0, 1) for s in (0, 1)]
    said = []
    lines = SplitLines(jobs, said.append)
    outputs = {1: _output("box", ["pca"], []), 2: _output("cup", ["pca"], []),
               3: _output("box", ["pca"], []), 4: _output("cup", ["pca"], [])}
    for i in (4, 2, 3):            # run 2 ends first; run 1's box (job 1) is still running
        lines(jobs[i], outputs[i])
    assert said == []
    lines(jobs[1], outputs[1])
    assert said == []              # the final models (job 0) are not done: nothing before them is said
    lines(jobs[0], (None, None, 0, {}))
    assert [line.split(" (")[0] for line in said] == ["run 1: loco test box", "run 1: loco test cup",
                                                      "run 2: loco test box", "run 2: loco test cup"]
    assert said[0] == "run 1: loco test box (10 train / 3 test frames)"


def test_a_failed_job_has_no_line_and_the_lines_after_it_still_come():
    jobs = [_job(0, 0), _job(0, 1)]
    said = []
    lines = SplitLines(jobs, said.append)
    lines(jobs[1], _output("cup", ["pca"], ["pca"]))
    lines(jobs[0], None)
    assert said == ["run 1: loco test cup (10 train / 3 test frames); declined: pca"]


def test_a_later_run_names_the_declines_it_reuses_from_run_1_as_the_summary_counts_them():
    jobs = [_job(0, 0), _job(1, 0)]
    said = []
    lines = SplitLines(jobs, said.append)
    lines(jobs[0], _output("cup", ["n3m", "sift-pnp", "smm", "pca"], ["n3m", "sift-pnp", "smm"]))
    lines(jobs[1], _output("cup", ["smm"], ["smm"]))   # n3m, sift-pnp and pca: fitted in run 1 only
    assert said[0].endswith("; declined: n3m, sift-pnp, smm")
    assert said[1] == ("run 2: loco test cup (10 train / 3 test frames); declined: n3m (reused from run 1), "
                       "sift-pnp (reused from run 1), smm")


def test_a_later_run_that_fits_nothing_says_every_method_is_reused():
    first = _output("cup", ["n3m", "pca"], ["n3m"])
    assert split_line(_job(2, 0), _output("cup", [], []), first) == (
        "run 3: loco test cup (10 train / 3 test frames); every method's predictions reused from run 1 "
        "(declined there: n3m)")
    assert split_line(_job(1, 0), _output("cup", [], []), _output("cup", ["pca"], [])).endswith(
        "every method's predictions reused from run 1")

import os
import signal
from pathlib import Path

import pytest

from spm_data.errors import SpmError
from spm_data.jobs.executor import run_jobs


def crashing_job(job, report):
    """job = (value, marker path or None, mode). Dies by SIGKILL per mode, else returns value * 2."""
    value, marker, mode = job
    report(1)
    if mode == "once" and not Path(marker).exists():
        Path(marker).write_text("died once")
        os.kill(os.getpid(), signal.SIGKILL)
    if mode == "always":
        os.kill(os.getpid(), signal.SIGKILL)
    if mode == "error":
        raise SpmError(f"bad job {value}")
    return value * 2


def test_results_in_job_order_with_progress():
    progress = []
    outcomes = run_jobs(crashing_job, [(i, None, "") for i in range(6)], workers=2, on_progress=progress.append)
    assert [o.result for o in outcomes] == [0, 2, 4, 6, 8, 10]
    assert sum(progress) == 6


def test_a_killed_worker_loses_only_its_job_which_is_retried(tmp_path):
    jobs = [(1, None, ""), (2, str(tmp_path / "m"), "once"), (3, None, ""), (4, None, "")]
    lost = []
    progress = []
    outcomes = run_jobs(crashing_job, jobs, workers=2, retries=1, on_worker_death=lost.append,
                        on_progress=progress.append)
    assert [o.result for o in outcomes] == [2, 4, 6, 8]
    assert [o.error for o in outcomes] == [None] * 4
    assert outcomes[1].attempts == 2 and lost == [jobs[1]]
    assert sum(progress) == 4  # the dead attempt's progress was taken back


def test_a_job_that_keeps_dying_is_reported_and_the_rest_finish():
    jobs = [(1, None, ""), (2, None, "always"), (3, None, ""), (5, None, "error")]
    outcomes = run_jobs(crashing_job, jobs, workers=2, retries=1)
    assert outcomes[0].result == 2 and outcomes[2].result == 6
    assert outcomes[1].error.startswith("worker died (signal 9) after 2 attempts")
    assert outcomes[3].error == "bad job 5"


@pytest.mark.parametrize("recycle_after, processes", [(2, 3), (0, 1)])
def test_workers_are_recycled_after_n_jobs(recycle_after, processes):
    from spm_data.jobs.outcome import probe_job

    outcomes = run_jobs(probe_job, list(range(5)), workers=1, recycle_after=recycle_after)
    pids = [o.result["pid"] for o in outcomes]
    assert [o.result["job"] for o in outcomes] == [0, 1, 2, 3, 4]
    # One worker at a time: a new process every recycle_after jobs (2 + 2 + 1), or one for all.
    assert len(set(pids)) == processes and os.getpid() not in pids
    if recycle_after:
        assert pids[0] == pids[1] != pids[2] == pids[3] != pids[4]


def test_in_process_mode():
    outcomes = run_jobs(crashing_job, [(1, None, ""), (2, None, "error")], workers=0)
    assert outcomes[0].result == 2 and outcomes[1].error == "bad job 2"


def test_the_parent_works_too_and_results_stay_in_job_order():
    """parent_works: this process runs jobs while the spawned worker starts (it takes the first
    job itself: no worker is ready then); an SpmError in its job is that job's error."""
    from spm_data.jobs.outcome import probe_job

    outcomes = run_jobs(probe_job, list(range(6)), workers=2, parent_works=True)
    assert [o.result["job"] for o in outcomes] == list(range(6))
    assert outcomes[0].result["pid"] == os.getpid()
    assert len({o.result["pid"] for o in outcomes}) <= 2  # the parent and at most one worker
    outcomes = run_jobs(crashing_job, [(2, None, "error"), (3, None, "")], workers=2, parent_works=True)
    assert outcomes[0].error == "bad job 2" and outcomes[1].result == 6


def blas_environment(job, report):
    return os.environ.get(job)


def test_spawned_workers_share_the_cores_among_their_blas_threads_unless_the_user_said(monkeypatch):
    monkeypatch.delenv("OPENBLAS_NUM_THREADS", raising=False)
    monkeypatch.setenv("MKL_NUM_THREADS", "3")
    expected = str(max(1, (os.cpu_count() or 1) // 2))
    got = run_jobs(blas_environment, ["OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"] * 2, workers=2)
    assert [o.result for o in got] == [expected, "3"] * 2
    assert "OPENBLAS_NUM_THREADS" not in os.environ  # the parent's environment as it was

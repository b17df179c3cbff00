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


# --------------------------------------------------------------------------- GPUs (render's --gpus)

def gpu_of_worker(job, report):
    from spm_data.render.base import GPU_VARIABLE

    return os.environ.get(GPU_VARIABLE), os.environ.get("SPM_WORKER_CORES"), os.getpid()


def test_workers_take_the_gpus_in_turn_and_in_process_jobs_the_first(monkeypatch):
    from spm_data.jobs.executor import worker_environment
    from spm_data.render.base import GPU_VARIABLE

    monkeypatch.setenv(GPU_VARIABLE, "")  # recorded as it is, so the test leaves it so
    monkeypatch.delenv(GPU_VARIABLE)
    assert [worker_environment(3, slot, (2, 5))[GPU_VARIABLE] for slot in range(4)] == ["2", "5", "2", "5"]
    assert GPU_VARIABLE not in worker_environment(3, 1, ())
    assert worker_environment(2)["SPM_WORKER_CORES"] == str(max(1, (os.cpu_count() or 1) // 2))
    got = run_jobs(gpu_of_worker, list(range(6)), workers=2, gpus=(4, 7))
    by_process = {pid: gpu for gpu, _, pid in (o.result for o in got)}
    assert sorted(by_process.values()) == ["4", "7"]  # two processes, one on each GPU
    here = run_jobs(gpu_of_worker, [0], workers=0, gpus=(3,))
    assert here[0].result[:2] == ("3", None) and GPU_VARIABLE not in os.environ  # restored after the run


def sigint_state(job, report):
    report(1)
    blocked = signal.pthread_sigmask(signal.SIG_BLOCK, [])
    return signal.getsignal(signal.SIGINT) == signal.SIG_IGN, signal.SIGINT in blocked


SPAWN_WHILE_HELD = """
import multiprocessing, signal, sys
from spm_data.jobs.executor import _sigint_held

def report(conn):
    conn.send(signal.SIGINT in signal.pthread_sigmask(signal.SIG_BLOCK, []))

if __name__ == "__main__":
    ctx = multiprocessing.get_context("spawn")
    reader, writer = ctx.Pipe(duplex=False)   # as the executor's workers: a Pipe (a Queue would start the tracker)
    with _sigint_held():
        proc = ctx.Process(target=report, args=(writer,))
        proc.start()
    if not reader.poll(120):
        sys.exit("the child said nothing")
    print(reader.recv(), signal.SIGINT in signal.pthread_sigmask(signal.SIG_BLOCK, []))
    proc.join(timeout=120)
"""


def test_a_process_spawned_while_sigint_is_held_starts_with_it_blocked(tmp_path):
    """Also the first process a program spawns (multiprocessing starts its resource tracker then),
    in a fresh interpreter; the parent's mask is as it was."""
    import subprocess
    import sys

    script = tmp_path / "spawn_while_held.py"
    script.write_text(SPAWN_WHILE_HELD)
    done = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=300,
                          cwd=Path(__file__).resolve().parents[2],
                          env={**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[2])})
    assert done.stdout.split() == ["True", "False"], done.stderr   # blocked through the child's start-up


def test_a_worker_starts_with_sigint_held_and_then_ignores_it_and_the_parent_keeps_its_own():
    """A Ctrl-C to the process group while a worker is still importing must not print from the
    worker: it is spawned with SIGINT blocked, and ignores it (unblocked) once it runs jobs."""
    before = signal.pthread_sigmask(signal.SIG_BLOCK, [])
    got = run_jobs(sigint_state, [0, 1], workers=2)
    assert [o.result for o in got] == [(True, False), (True, False)]
    assert signal.pthread_sigmask(signal.SIG_BLOCK, []) == before and signal.SIGINT not in before


def test_a_spawned_worker_of_the_programs_does_not_take_their_early_signal_handlers(tmp_path):
    """cli.py, run again in a spawned worker (the program's main script is imported there with the
    parent's sys.argv), leaves the worker's signals alone."""
    import subprocess
    import sys

    # Python's own SIGINT handler first: a suite started in the background (`cmd &`) inherits SIG_IGN.
    code = ("import sys, signal; signal.signal(signal.SIGINT, signal.default_int_handler); "
            "sys.argv = ['/usr/bin/spm-data']; import cli; "
            "print(signal.getsignal(signal.SIGINT) is signal.default_int_handler)")
    for extra, want in (([], "False"), (["--multiprocessing-fork"], "True")):
        done = subprocess.run([sys.executable, "-c", code, *extra], capture_output=True, text=True, timeout=120,
                              cwd=Path(__file__).resolve().parents[2])
        assert done.stdout.strip() == want, done.stderr


def warning_job(job, report):
    """Warns as the library does (an SpmWarning), then returns the job."""
    import warnings

    from spm_data.errors import SpmWarning

    warnings.warn(f"feature memo entry {job} is damaged", SpmWarning)
    report(1)
    return job


def test_a_workers_warning_is_one_warning_line(capfd):
    """Issue 47: a worker printed the memo's warning as two lines in Python's warnings format
    (`FILE:LINE: SpmWarning: …` and the source line)."""
    outcomes = run_jobs(warning_job, ["a", "b"], workers=2)
    assert [o.result for o in outcomes] == ["a", "b"]
    lines = capfd.readouterr().err.splitlines()
    assert sorted(lines) == ["warning: feature memo entry a is damaged", "warning: feature memo entry b is damaged"]

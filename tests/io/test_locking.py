"""The output folder's lock: one winner among racing processes, stale only when the
owner is on this host and gone, another host's lock never broken."""

import json
import multiprocessing
import os
import socket
import subprocess

import pytest

from tests.helpers import reaped
from spm_data.io import locking
from spm_data.errors import LockError, SpmError
from spm_data.io.locking import LOCK_NAME, LockOwner, OutputLock, lock_owner

HOST = socket.gethostname()
SINCE = "2026-11-22 17:40:02+00:00"
TRIALS = 200


def dead_pid():
    """The pid of a process that has exited and been reaped."""
    proc = subprocess.Popen(["true"])
    proc.wait()
    return proc.pid


def start_ticks(pid):
    """Field 22 of /proc/<pid>/stat: when the process started, in clock ticks since boot."""
    with open(f"/proc/{pid}/stat", "rb") as fh:
        return int(fh.read().rsplit(b")", 1)[1].split()[19])


def plant(folder, pid, host=HOST, ticks=None, token="planted", **more):
    """Write a lock record as spm would and return its bytes."""
    data = (json.dumps({"pid": pid, "host": host, "started": SINCE, "token": token, "ticks": ticks, **more})
            + "\n").encode()
    (folder / LOCK_NAME).write_bytes(data)
    return data


def leftovers(folder):
    """What a lock leaves in a folder besides the lock: nothing (not the guard either)."""
    return sorted(p.name for p in folder.iterdir() if p.name != LOCK_NAME)


def _racer(folders, barrier, results, me):
    """Take each folder's lock together with the other racer; report, then (the winner)
    hold it until the other has reported too."""
    try:
        for i, folder in enumerate(folders):
            lock = OutputLock(folder)
            barrier.wait(timeout=120)
            try:
                lock.acquire()
                outcome = ("won", "")
            except LockError as e:
                outcome = ("lost", str(e))
            results.put((i, me, os.getpid(), *outcome))
            barrier.wait(timeout=120)   # both have reported
            lock.release()
    except BaseException as e:  # noqa: BLE001 - reported to the test, which fails on it
        results.put((-1, me, os.getpid(), "error", repr(e)))
        barrier.abort()


@pytest.mark.slow  # 200 racing pairs of processes
@pytest.mark.parametrize("planted", ["none", "stale", "stale pid-only"])
def test_of_two_racing_processes_exactly_one_takes_the_lock(tmp_path, planted):
    folders = []
    gone = dead_pid()
    for i in range(TRIALS):
        folder = tmp_path / f"t{i}"
        folder.mkdir()
        if planted == "stale":
            plant(folder, gone, ticks=1)
        elif planted == "stale pid-only":
            (folder / LOCK_NAME).write_text(f"{gone}\n")
        folders.append(folder)
    ctx = multiprocessing.get_context("fork")
    barrier, results = ctx.Barrier(2), ctx.Queue()
    racers = [ctx.Process(target=_racer, args=(folders, barrier, results, me), daemon=True) for me in (0, 1)]
    for p in racers:
        p.start()
    try:
        reports = [results.get(timeout=120) for _ in range(2 * TRIALS)]
    finally:
        for p in racers:
            p.join(timeout=60)
            if p.is_alive():
                p.kill()
    assert [r for r in reports if r[3] == "error"] == []
    pids = {p.pid for p in racers}
    for i in range(TRIALS):
        trial = sorted((r for r in reports if r[0] == i), key=lambda r: r[3], reverse=True)
        assert [r[3] for r in trial] == ["won", "lost"], (i, trial)
        winner, loser = trial
        assert {winner[2], loser[2]} == pids
        assert loser[4].startswith(f"another run is writing to {folders[i]}/ (pid {winner[2]} on host {HOST}, "
                                   "since "), loser
        assert not (folders[i] / LOCK_NAME).exists() and leftovers(folders[i]) == []


def test_another_hosts_lock_is_never_broken(tmp_path):
    gone = dead_pid()   # dead here, which says nothing about the other host
    data = plant(tmp_path, gone, host="other-host", ticks=1)
    with pytest.raises(LockError) as e:
        OutputLock(tmp_path).acquire()
    assert str(e.value) == (
        f"{tmp_path}/ is locked by pid {gone} on host other-host (since {SINCE}); spm cannot tell from here "
        f"whether that run is still going: if it is not, delete {tmp_path}/{LOCK_NAME}")
    assert isinstance(e.value, SpmError) and "\n" not in str(e.value)
    assert (tmp_path / LOCK_NAME).read_bytes() == data and leftovers(tmp_path) == []
    assert lock_owner(tmp_path) == LockOwner(gone, "other-host", SINCE, "planted")
    # Deleting the file, as the message says, clears it.
    (tmp_path / LOCK_NAME).unlink()
    with OutputLock(tmp_path):
        assert lock_owner(tmp_path).pid == os.getpid()


@pytest.mark.parametrize("case", ["pid reused", "rebooted since"])
def test_a_live_pid_of_another_process_or_boot_is_stale(tmp_path, case):
    with reaped(subprocess.Popen(["sleep", "60"])) as other:
        ticks = start_ticks(other.pid)
        if case == "pid reused":
            plant(tmp_path, other.pid, ticks=ticks + 1)
        else:
            plant(tmp_path, other.pid, ticks=ticks, boot="a-boot-before-this-one")
        assert lock_owner(tmp_path) is None
        with OutputLock(tmp_path) as lock:
            assert lock.held and lock_owner(tmp_path).pid == os.getpid()
        assert not lock.path.exists()


def test_a_live_owner_on_this_host_is_refused_and_named(tmp_path):
    with reaped(subprocess.Popen(["sleep", "60"])) as other:
        data = plant(tmp_path, other.pid, ticks=start_ticks(other.pid), boot=locking._boot_id())
        with pytest.raises(LockError) as e:
            OutputLock(tmp_path).acquire()
        assert str(e.value) == (f"another run is writing to {tmp_path}/ (pid {other.pid} on host {HOST}, "
                                f"since {SINCE}); wait for it to finish or stop it")
        assert (tmp_path / LOCK_NAME).read_bytes() == data and leftovers(tmp_path) == []
        assert lock_owner(tmp_path) == LockOwner(other.pid, HOST, SINCE, "planted")
        assert str(lock_owner(tmp_path)) == f"pid {other.pid} on host {HOST}, since {SINCE}"


def test_pid_only_locks_of_older_versions(tmp_path):
    lock = tmp_path / LOCK_NAME
    # A dead pid: taken over.
    lock.write_text(f"{dead_pid()}\n")
    assert lock_owner(tmp_path) is None
    with OutputLock(tmp_path):
        assert json.loads(lock.read_text())["pid"] == os.getpid()
    assert not lock.exists()
    with reaped(subprocess.Popen(["sleep", "60"])) as other:
        # A live pid whose process started before the file was written: refused.
        lock.write_text(f"{other.pid}\n")
        with pytest.raises(LockError, match=rf"^another run is writing to {tmp_path}/ \(pid {other.pid} on host "
                                            rf"{HOST}\); wait for it to finish or stop it$"):
            OutputLock(tmp_path).acquire()
        assert lock_owner(tmp_path) == LockOwner(other.pid, HOST)
        # The same pid, but the file was written an hour before its process started: reused, taken over.
        stamp = os.stat(lock).st_mtime - 3600
        os.utime(lock, (stamp, stamp))
        assert lock_owner(tmp_path) is None
        with OutputLock(tmp_path):
            assert lock_owner(tmp_path).pid == os.getpid()


def test_an_unreadable_lock_is_taken_only_once_old(tmp_path, monkeypatch):
    lock = tmp_path / LOCK_NAME
    lock.write_bytes(b"")   # an older spm between making the file and writing its pid
    assert lock_owner(tmp_path) == LockOwner(0, "")
    stamp = os.stat(lock).st_mtime - 60
    os.utime(lock, (stamp, stamp))
    assert lock_owner(tmp_path) is None
    with OutputLock(tmp_path):
        assert lock_owner(tmp_path).pid == os.getpid()
    # A young one is waited for until it is old enough (here 0.2 s), then taken.
    monkeypatch.setattr(locking, "UNREADABLE_AGE", 0.2)
    lock.write_bytes(b"{garbage")
    with OutputLock(tmp_path):
        assert lock_owner(tmp_path).pid == os.getpid()
    assert not lock.exists() and leftovers(tmp_path) == []


def test_lock_owner_changes_nothing(tmp_path):
    assert lock_owner(tmp_path) is None and list(tmp_path.iterdir()) == []
    data = plant(tmp_path, dead_pid(), ticks=1)
    assert lock_owner(tmp_path) is None   # stale
    assert (tmp_path / LOCK_NAME).read_bytes() == data and leftovers(tmp_path) == []
    assert lock_owner(tmp_path / "missing") is None


def test_the_record_names_the_owner_and_release_removes_only_its_own(tmp_path):
    lock = OutputLock(tmp_path)
    lock.acquire()
    record = json.loads(lock.path.read_text())
    assert record["pid"] == os.getpid() and record["host"] == HOST and record["ticks"] == start_ticks(os.getpid())
    owner = lock_owner(tmp_path)
    assert owner == LockOwner(os.getpid(), HOST, record["started"], record["token"]) and owner.token
    with pytest.raises(LockError, match=rf"\(pid {os.getpid()} on host {HOST}, since "):
        OutputLock(tmp_path).acquire()   # a second lock, even in the same process
    # A forked child's copy of the lock leaves it to the parent.
    child = multiprocessing.get_context("fork").Process(target=lock.release)
    child.start()
    child.join(timeout=60)
    assert child.exitcode == 0 and lock_owner(tmp_path) == owner
    # Someone else's record in its place (the lock was broken and taken): kept.
    other = plant(tmp_path, os.getpid(), ticks=start_ticks(os.getpid()), token="someone-else")
    lock.release()
    assert not lock.held and lock.path.read_bytes() == other
    lock.path.unlink()
    with OutputLock(tmp_path) as again:
        assert again.held
    assert not again.held and list(tmp_path.iterdir()) == []


def test_a_stale_lock_taken_over_leaves_no_guard(tmp_path):
    """The guard made to take over a stale lock (as after kill -9) goes with the takeover."""
    plant(tmp_path, dead_pid(), ticks=1)
    with OutputLock(tmp_path):
        assert sorted(p.name for p in tmp_path.iterdir()) == [LOCK_NAME]
    assert list(tmp_path.iterdir()) == []


def test_a_guard_left_by_a_killed_takeover_is_removed(tmp_path):
    guard = tmp_path / locking.GUARD_NAME
    guard.write_bytes(b"")   # a run killed between making the guard and removing it; or an older spm's
    with OutputLock(tmp_path):
        pass
    assert list(tmp_path.iterdir()) == []
    guard.write_bytes(b"")
    plant(tmp_path, dead_pid(), ticks=1)
    with OutputLock(tmp_path):
        assert not guard.exists()
    assert list(tmp_path.iterdir()) == []


def test_a_guard_in_use_is_left_to_its_holder(tmp_path):
    guard = tmp_path / locking.GUARD_NAME
    fd = os.open(guard, os.O_RDWR | os.O_CREAT)
    try:
        locking.fcntl.flock(fd, locking.fcntl.LOCK_EX)   # another run, taking over a lock
        with OutputLock(tmp_path):
            pass
        assert guard.exists()
    finally:
        os.close(fd)


def test_a_waiter_whose_guard_was_removed_locks_the_new_one(tmp_path):
    """The race removing the guard could open: B waits on the guard's file; its holder removes it
    and a third run makes a new guard and holds it; B, given the old file's flock, must not run
    beside that third run, but wait for the new guard."""
    import threading
    import time

    guard = tmp_path / locking.GUARD_NAME
    fcntl = locking.fcntl
    old = os.open(guard, os.O_RDWR | os.O_CREAT)
    fcntl.flock(old, fcntl.LOCK_EX)
    ran = []
    waiter = threading.Thread(target=lambda: ran.append(locking._guarded(guard, lambda: ran.append(time.monotonic()),
                                                                          wait=True)))
    waiter.start()
    time.sleep(0.3)   # B has opened the old file and waits on its flock
    guard.unlink()    # its holder removes it (under its flock), as _guarded does
    new = os.open(guard, os.O_RDWR | os.O_CREAT)
    fcntl.flock(new, fcntl.LOCK_EX)   # a third run's new guard
    os.close(old)     # the old file's flock goes to B
    time.sleep(0.3)
    assert ran == []  # B saw that the file it locked is no longer the guard, and waits for the new one
    freed = time.monotonic()
    os.close(new)
    waiter.join(timeout=30)
    assert len(ran) == 2 and ran[0] >= freed and ran[1] is True and not guard.exists()

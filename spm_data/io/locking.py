"""One writer per output folder: ``folder/.spm.lock`` names its owner.

The lock file is made in one atomic step with its whole content: the owner
record (JSON: pid, host, boot id, the process's start time in clock ticks from
``/proc/<pid>/stat``, the time the lock was taken and a random token) is written
to a temporary file in the same folder, synced, then hard-linked to the lock's
name (``os.link`` fails if the lock exists), so no one ever sees a lock without
its owner.

A lock is stale only when its owner is on this host and gone: the machine was
rebooted since, the pid is not running (or is a zombie), or the pid now runs
another process (its start time differs). A lock of another host is never
broken: spm cannot see that host's processes. A stale lock is removed under a
short ``flock`` on ``.spm.lock.guard`` and only if it still holds the record
judged stale, so two runs taking over the same stale lock cannot both win. The
guard is removed by the run that made it, still under its flock, before that
flock is freed (``_guarded`` says why that stays race-free), so no ``.spm.lock*``
file outlives a run.

Files of older spm versions hold only a pid: they are read as an owner on this
host whose start time is unknown (the pid was reused if its process started
after the file was written).
"""

from __future__ import annotations

import datetime
import fcntl
import functools
import json
import os
import secrets
import socket
import time
from dataclasses import dataclass
from pathlib import Path

from spm_data.errors import LockError

LOCK_NAME = ".spm.lock"
GUARD_NAME = LOCK_NAME + ".guard"
UNREADABLE_AGE = 5.0   # s: an unreadable lock younger than this may still be being written (older spm)
LEGACY_SLACK = 5.0     # s: a pid-only lock's process must have started before the file was written
TAKE_TIMEOUT = 30.0    # s: give up when other runs keep taking and dropping the lock


@dataclass(frozen=True)
class LockOwner:
    """Who holds a lock: ``started`` is when it was taken (ISO, "" if unknown), ``token`` "" for old files."""

    pid: int
    host: str
    started: str = ""
    token: str = ""

    def __str__(self) -> str:
        """"pid 123 on host h, since T" (or that the lock file is unreadable), for messages."""
        if self.pid <= 0:
            return "an unknown run (its lock file is unreadable)"
        return f"pid {self.pid} on host {self.host}" + (f", since {self.started}" if self.started else "")


@dataclass(frozen=True)
class _Record:
    owner: LockOwner
    ticks: int | None = None   # the owner's start time, /proc/<pid>/stat field 22
    boot: str | None = None    # /proc/sys/kernel/random/boot_id when it was taken


def _host() -> str:
    return socket.gethostname()


@functools.cache
def _boot_id() -> str | None:
    try:
        return Path("/proc/sys/kernel/random/boot_id").read_text().strip() or None
    except OSError:
        return None


@functools.cache
def _boot_time() -> float | None:
    try:
        for line in Path("/proc/stat").read_text().splitlines():
            if line.startswith("btime "):
                return float(line.split()[1])
    except (OSError, ValueError, IndexError):
        pass
    return None


def _proc_stat(pid: int) -> tuple[str, int] | None:
    """(state, start time in clock ticks since boot) of ``pid``, or None without /proc or process."""
    try:
        data = Path(f"/proc/{pid}/stat").read_bytes()
        fields = data[data.rindex(b")") + 2:].split()   # the name, in parentheses, may hold anything
        return fields[0].decode(), int(fields[19])      # fields 3 and 22
    except (OSError, ValueError, IndexError):
        return None


def pid_alive(pid: int) -> bool:
    """Whether process ``pid`` of this host is running (a zombie is not)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        pass   # another user's process
    stat = _proc_stat(pid)
    return stat is None or stat[0] != "Z"


def _parse(raw: bytes) -> _Record | None:
    """The record in a lock file's bytes, or None if they are not one."""
    try:
        text = raw.decode("utf-8").strip()
        if text.isdigit():   # older spm: the pid alone, always on this host
            pid = int(text)
            return _Record(LockOwner(pid, _host())) if 0 < pid < 2**31 else None
        d = json.loads(text)
        pid, host = d["pid"], d["host"]
        ticks, boot = d.get("ticks"), d.get("boot")
        started, token = d.get("started") or "", d.get("token") or ""
    except (UnicodeDecodeError, ValueError, TypeError, KeyError):
        return None
    ok = (type(pid) is int and 0 < pid < 2**31 and isinstance(host, str) and host
          and (ticks is None or type(ticks) is int) and (boot is None or isinstance(boot, str))
          and isinstance(started, str) and isinstance(token, str))
    return _Record(LockOwner(pid, host, started, token), ticks, boot) if ok else None


def _is_stale(rec: _Record, mtime: float) -> bool:
    """True only if the owner is on this host and gone."""
    pid = rec.owner.pid
    if rec.owner.host != _host():
        return False
    if rec.boot and _boot_id() and rec.boot != _boot_id():
        return True   # taken before this machine last booted
    if not pid_alive(pid):
        return True
    stat = _proc_stat(pid)
    if stat is None:
        return False  # alive, and nothing more to tell
    if rec.ticks is not None:
        return stat[1] != rec.ticks   # the pid was reused
    boot = _boot_time()
    return boot is not None and boot + stat[1] / os.sysconf("SC_CLK_TCK") > mtime + LEGACY_SLACK


def _read(path: Path) -> tuple[bytes | None, float]:
    """The lock's bytes and modification time; (None, 0) if there is no lock."""
    try:
        with open(path, "rb") as fh:
            return fh.read(), os.fstat(fh.fileno()).st_mtime
    except (FileNotFoundError, NotADirectoryError):
        return None, 0.0


def lock_owner(folder) -> LockOwner | None:
    """The owner of ``folder``'s lock if it is held (by a live process on this host
    or by any process on another host); None if there is no lock or it is stale.
    Reads only: changes nothing."""
    try:
        raw, mtime = _read(Path(folder) / LOCK_NAME)
    except OSError:   # there, but not ours to read: someone holds it
        return LockOwner(0, "")
    if raw is None:
        return None
    rec = _parse(raw)
    if rec is None:
        return LockOwner(0, "") if time.time() - mtime < UNREADABLE_AGE else None
    return None if _is_stale(rec, mtime) else rec.owner


def _guarded(guard: Path, work, wait: bool) -> bool:
    """Run ``work()`` holding an exclusive ``flock`` on the file ``guard``, then remove ``guard``
    (still holding the flock), so that the guard does not outlive the takeover that made it.
    ``wait``: create the guard if missing and wait for its flock; else do nothing (False) if
    there is no guard or another run holds it.

    Removing a file others may be waiting to flock needs one more step to stay race-free: a
    run that waited on the guard's file may get its flock only after the holder has removed
    it, while a third run has made a new guard and holds that one; both would then believe
    they hold "the" guard. So whoever gets a flock checks that the name ``guard`` still
    refers to the file it locked (same device and inode) and, if not, lets go and starts over
    with the file now there. Only the holder of the file at the name removes it, so at most
    one run at a time holds a flock on the file that is at the name: the mutual exclusion of
    a guard that is never removed. (The flock is freed if its holder dies, as before; a guard
    left that way is removed by the next takeover or release.)"""
    while True:
        try:
            fd = os.open(guard, os.O_RDWR | (os.O_CREAT if wait else 0), 0o644)
        except FileNotFoundError:
            return False
        try:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX if wait else fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                return False   # another run is taking over a lock: it removes the guard after
            held = os.fstat(fd)
            try:
                there = os.stat(guard)
            except FileNotFoundError:
                there = None
            if there is None or (there.st_dev, there.st_ino) != (held.st_dev, held.st_ino):
                if wait:
                    continue   # the file we locked was removed by its holder: lock the one there now
                return False
            work()
            guard.unlink(missing_ok=True)
            return True
        finally:
            os.close(fd)   # frees the flock, after the unlink


class OutputLock:
    """Context manager: ``with OutputLock(out): ...`` holds ``out/.spm.lock``.

    ``acquire()`` raises LockError if another run holds it; ``release()`` removes
    the lock only if it still holds this lock's record."""

    def __init__(self, folder):
        self.path = Path(folder) / LOCK_NAME
        self.held = False
        self._data = b""
        self._pid = 0

    def acquire(self) -> None:
        if self.held:
            raise RuntimeError(f"{self.path} is already held by this OutputLock")
        pid = os.getpid()
        owner = LockOwner(pid, _host(), datetime.datetime.now().astimezone().isoformat(" ", "seconds"),
                          secrets.token_hex(8))
        stat = _proc_stat(pid)
        data = (json.dumps({"pid": pid, "host": owner.host, "started": owner.started, "token": owner.token,
                            "ticks": stat[1] if stat else None, "boot": _boot_id()}) + "\n").encode()
        tmp = self.path.with_name(f"{LOCK_NAME}.{pid}.{owner.token}.tmp")
        deadline = time.monotonic() + TAKE_TIMEOUT
        fd = os.open(tmp, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
        try:
            try:
                os.write(fd, data)
                os.fsync(fd)
            finally:
                os.close(fd)
            while True:
                try:
                    os.link(tmp, self.path)
                except FileExistsError:
                    pass
                else:
                    self.held, self._data, self._pid = True, data, pid
                    return
                raw, mtime = _read(self.path)
                if raw is None:
                    continue   # released meanwhile: try again
                rec = _parse(raw)
                if rec is not None and not _is_stale(rec, mtime):
                    raise LockError(self._refusal(rec.owner))
                if time.monotonic() > deadline:
                    raise LockError(f"could not take {self.path}: " + (
                        "other runs keep taking it; try again" if rec else
                        f"it stays unreadable; if no run is writing to {self.path.parent}/, delete it"))
                if rec is None and time.time() - mtime < UNREADABLE_AGE:
                    time.sleep(0.05)   # maybe an older spm between making the file and writing its pid
                else:
                    self._break(raw)
        finally:
            tmp.unlink(missing_ok=True)

    def _refusal(self, owner: LockOwner) -> str:
        out = self.path.parent
        if owner.host == _host():
            return (f"another run is writing to {out}/ ({owner}); "
                    "wait for it to finish or stop it")
        since = f" (since {owner.started})" if owner.started else ""
        return (f"{out}/ is locked by pid {owner.pid} on host {owner.host}{since}; spm cannot tell from "
                f"here whether that run is still going: if it is not, delete {self.path}")

    def _break(self, stale: bytes) -> None:
        """Remove the lock if it still holds ``stale``, under the guard so that of two
        runs which judged the same lock stale, only one removes it (not the other's)."""
        def remove_if_stale():
            if _read(self.path)[0] == stale:
                self.path.unlink(missing_ok=True)

        _guarded(self.path.with_name(GUARD_NAME), remove_if_stale, wait=True)

    def release(self) -> None:
        if not self.held:
            return
        self.held = False
        if os.getpid() != self._pid:
            return   # a forked child's copy: the lock is its parent's
        if _read(self.path)[0] == self._data:
            self.path.unlink(missing_ok=True)
        # A guard left by a run killed inside _break: removed unless some run is using it now.
        _guarded(self.path.with_name(GUARD_NAME), lambda: None, wait=False)

    def __enter__(self):
        self.acquire()
        return self

    def __exit__(self, *exc):
        self.release()
        return False

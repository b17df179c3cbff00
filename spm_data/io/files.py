"""Files written whole or not at all, and file hashes.

Every file the library writes goes to a hidden ``.NAME.partial`` beside its
target and is ``os.replace``-d into place when complete: a reader sees the old
file or the whole new one, never half (shards, manifests, models, caches, reports).
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import json
import os
import stat
from pathlib import Path

import numpy as np

PARTIAL_PREFIX = "."
PARTIAL_SUFFIX = ".partial"


def partial_path(path: Path) -> Path:
    return path.with_name(PARTIAL_PREFIX + path.name + PARTIAL_SUFFIX)


def file_sha256(path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


@contextlib.contextmanager
def atomic_file(path, tmp=None):
    """Yield a temporary path beside ``path`` (default ``.NAME.partial``); when the
    block completes it becomes ``path`` (os.replace), when it raises it is removed,
    so ``path`` is either the old file or the whole new one."""
    path = Path(path)
    tmp = Path(tmp) if tmp is not None else partial_path(path)
    try:
        yield tmp
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def write_npz_atomic(path, tmp=None, **arrays) -> Path:
    """``np.savez`` to ``path`` atomically (atomic_file). Built in memory, then written in
    one go: np.savez leaves its zip file open when a write fails (disk full), and Python
    then prints that zip file's error on exit, after our one-line message."""
    npz = io.BytesIO()
    np.savez(npz, **arrays)
    with atomic_file(path, tmp) as partial, open(partial, "wb") as fh:
        fh.write(npz.getbuffer())
    return Path(path)


def write_json_atomic(path, payload, sort_keys: bool = True) -> None:
    with atomic_file(path) as tmp, open(tmp, "w") as fh:
        json.dump(payload, fh, indent=2, sort_keys=sort_keys)
        fh.write("\n")
        fh.flush()
        os.fsync(fh.fileno())


def file_kind(mode: int) -> str:
    """What a file that is not a regular one is, in words ("a FIFO", "a character device", …)."""
    return ("a FIFO" if stat.S_ISFIFO(mode) else "a character device" if stat.S_ISCHR(mode) else
            "a block device" if stat.S_ISBLK(mode) else "a socket" if stat.S_ISSOCK(mode) else "not a plain file")


def read_regular_file(path, limit: int) -> bytes:
    """The bytes of a regular file of at most ``limit`` bytes. OSError for a missing or unreadable
    file; ValueError(reason) for a folder ("is a folder"), anything that is not a regular file (a
    FIFO, a device such as /dev/zero: refused without reading or waiting: "is a FIFO") and a
    file over ``limit`` (refused before reading: "N bytes is over the limit of L bytes")."""
    fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK)  # a FIFO opens at once, not when a writer comes
    st = os.fstat(fd)
    if not stat.S_ISREG(st.st_mode):
        os.close(fd)
        raise ValueError("is a folder" if stat.S_ISDIR(st.st_mode) else f"is {file_kind(st.st_mode)}")
    with os.fdopen(fd, "rb", buffering=0) as fh:
        data = _read_at_most(fh, limit + 1, first=st.st_size + 1, size=st.st_size) if st.st_size <= limit else b""
    if st.st_size > limit or len(data) > limit:
        raise ValueError(f"{max(st.st_size, len(data)):,} bytes is over the limit of {limit:,} bytes")
    return data


def _read_at_most(fh, most: int, first: int, size: int) -> bytes:
    """Up to ``most`` bytes of ``fh``: ``first`` bytes (what the file held, and one more to see it
    grow), then 1 MiB pieces; never an allocation of ``most`` bytes up front (a 4 GiB limit under
    ``ulimit -v`` was a MemoryError). ValueError when what the file holds does not fit in memory."""
    pieces, got = [], 0
    try:
        while got < most:
            piece = fh.read(min(first if not pieces else 1 << 20, most - got))
            if not piece:
                break
            pieces.append(piece)
            got += len(piece)
        return b"".join(pieces)   # one piece (the usual case): that piece itself, not a copy
    except MemoryError:
        raise ValueError(f"its {size:,} bytes do not fit in this process's memory (ulimit -v?)") from None

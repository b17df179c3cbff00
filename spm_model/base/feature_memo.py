"""A memo of per-image features, keyed by the image's content: in memory per process,
and in a folder shared by processes and runs when the benchmark names one.

Methods that extract local features inside ``fit`` and ``predict`` (N3M, SMM) see the
same images again and again in a benchmark: under ``loco`` every frame trains in five
of the six folds of each run and is tested in one, so SMM extracted SIFT about 15
times per frame and run, in every worker, and again under the next protocol. The memo
returns the arrays computed the first time. The key is a hash of the pixels the method
was given (and the method's feature parameters), so it knows nothing a camera would not
show: it is the method's own deterministic function, remembered, and results are
identical with or without it.

Memory: each process keeps at most ``SPM_FEATURE_MEMO_MB`` megabytes (default 2048;
0 turns the memo off, the folder too). Once full, new features are not kept in memory
(an LRU would evict every entry before its reuse when folds sweep a set larger than the
budget; keeping the first ones gives a hit rate of about budget / working set).

Folder: ``spm train``'s workers use ``<feature cache>/memo/`` (spm_model/bench/protocols.py),
one ``.feat`` file per image and method (:func:`save_entry`: the content key of the input it
was computed from, the arrays' raw bytes and a digest over both), written to a temporary
name and renamed. A read checks the digest and that the key inside is the key asked for, so
a damaged, cut-short, renamed, swapped or foreign entry (another image's, another version's,
an earlier format's) is recomputed and rewritten, never used; the first one in a process is
said in one ``warning:`` line. About 50 KB per 128-pixel frame for N3M and SMM together;
delete the folder to reclaim the space.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import socket
import struct
import warnings
from pathlib import Path
from typing import Callable

import numpy as np

from spm_data.errors import SpmWarning
from spm_data.io.locking import pid_alive

DEFAULT_MB = 2048

_entries: dict[bytes, tuple] = {}
_stats = {"bytes": 0, "hits": 0, "misses": 0, "disk_hits": 0}
_folder: list = [None]  # the process's memo folder, or None
_warned: list = [False]  # whether this process has said that an entry was refused


def budget_bytes() -> int:
    """The memo's size limit in bytes, from ``SPM_FEATURE_MEMO_MB`` (default 2048 MB)."""
    text = os.environ.get("SPM_FEATURE_MEMO_MB", "").strip()
    try:
        mb = float(text) if text else DEFAULT_MB
    except ValueError:
        mb = DEFAULT_MB  # a malformed setting must not stop a benchmark; the default applies
    return int(max(mb, 0.0) * 2 ** 20)


def use_folder(folder) -> None:
    """Keep features in ``folder`` too (None: memory only); it is created on first write.
    Files half-written by processes of this host that are gone (killed) are removed."""
    _folder[0] = None if folder is None else Path(folder)
    if _folder[0] is None or not _folder[0].is_dir():
        return
    host = socket.gethostname()
    for path in _folder[0].glob("*/.*.partial"):
        parts = path.name.rsplit(".", 3)  # .KEY . host . pid . partial
        if len(parts) == 4 and parts[1] == host and parts[2].isdigit() and not pid_alive(int(parts[2])):
            path.unlink(missing_ok=True)


# What picks the CPU code of the libraries features are computed with (spm_model/bench/isolation.py).
CODE_PATH_VARIABLES = ("OPENBLAS_CORETYPE", "NPY_DISABLE_CPU_FEATURES", "OPENCV_CPU_DISABLE")


def content_key(kind: tuple, *arrays) -> bytes:
    """A 20-byte key of ``kind`` (the feature's name and parameters, reprs compared), the CPU code
    the process was pinned to (CODE_PATH_VARIABLES: features computed by other code paths differ
    in their last bits, so they are never served for these) and the arrays' dtypes, shapes and bytes."""
    pinned = tuple(os.environ.get(name, "") for name in CODE_PATH_VARIABLES)
    h = hashlib.blake2b(repr((kind, pinned) if any(pinned) else kind).encode(), digest_size=20)
    for a in arrays:
        a = np.ascontiguousarray(a)
        h.update(f"{a.dtype.str}{a.shape}".encode())
        h.update(a.data if a.size else b"")
    return h.digest()


MAGIC = b"SPMFEAT2"  # 2: the content key inside the digest (1 had none: a renamed entry was served)
DIGEST = 20     # bytes of the blake2b digest that ends a file; also the length of a content key
ALIGN = 16      # each array's bytes start at a multiple of this, so they are read in place
NO_KEY = bytes(DIGEST)


def save_entry(path, arrays, key: bytes = NO_KEY) -> None:
    """Write ``arrays`` (a tuple of numpy arrays of plain dtypes), computed from the input whose
    :func:`content_key` is ``key``, to ``path``: MAGIC, the key (DIGEST bytes), the count (uint32),
    per array its dtype string (uint8 length, ASCII), ndim (uint8) and shape (int64 each), then
    each array's C-order bytes at an ALIGN-byte boundary, then the blake2b digest (DIGEST
    bytes) of everything before it. Little-endian."""
    if len(key) != DIGEST:
        raise ValueError(f"save_entry: a content key is {DIGEST} bytes, got {len(key)}")
    head = [MAGIC, bytes(key), struct.pack("<I", len(arrays))]
    arrays = [np.asarray(a, order="C") for a in arrays]
    if any(a.dtype.hasobject or a.dtype.names is not None for a in arrays):
        raise ValueError("save_entry: arrays of Python objects or of named fields are not stored; "
                         "give plain arrays (one per field)")
    for a in arrays:
        code = a.dtype.str.encode()
        head.append(struct.pack(f"<B{len(code)}sB{a.ndim}q", len(code), code, a.ndim, *a.shape))
    parts, size = head, sum(len(h) for h in head)
    for a in arrays:
        parts.append(bytes(-size % ALIGN))
        parts.append(a.tobytes())
        size += len(parts[-2]) + a.nbytes
    body = b"".join(parts)
    with open(path, "wb") as f:
        f.write(body + hashlib.blake2b(body, digest_size=DIGEST).digest())


def load_entry(path, key: bytes = NO_KEY) -> tuple | None:
    """The arrays :func:`save_entry` wrote to ``path`` for ``key`` (read-only views of the file's
    bytes), or None when the file is missing, damaged, cut short, of another format, or was
    computed from another input (its key is not ``key``)."""
    try:
        with open(path, "rb") as f:
            data = f.read()
    except OSError:
        return None
    body, start = memoryview(data)[:-DIGEST], len(MAGIC) + DIGEST
    if len(data) < start + 4 + DIGEST or data[:len(MAGIC)] != MAGIC or \
            hashlib.blake2b(body, digest_size=DIGEST).digest() != data[-DIGEST:]:
        return None  # damaged or half-written by a killed process: recomputed and rewritten
    if data[len(MAGIC):start] != key:
        return None  # a sound entry of another input (renamed, swapped, copied): never served
    try:
        (count,), at, specs = struct.unpack_from("<I", data, start), start + 4, []
        for _ in range(count):
            length = data[at]
            dtype, ndim = np.dtype(data[at + 1:at + 1 + length].decode()), data[at + 1 + length]
            specs.append((dtype, struct.unpack_from(f"<{ndim}q", data, at + 2 + length)))
            at += 2 + length + 8 * ndim
        out = []
        for dtype, shape in specs:
            at += -at % ALIGN
            n = int(np.prod(shape, dtype=np.int64))
            out.append(np.frombuffer(body, dtype=dtype, count=n, offset=at).reshape(shape))
            at += n * dtype.itemsize
    except (ValueError, TypeError, IndexError, struct.error):
        return None
    return tuple(out) if at == len(body) else None


def _path(key: bytes) -> Path:
    name = key.hex()
    return _folder[0] / name[:2] / f"{name}.feat"


def _read(key: bytes) -> tuple | None:
    """The folder's entry for ``key``; None when there is none or it cannot be used (said once)."""
    path = _path(key)
    if not path.exists():
        # Looked for first: an entry another worker renames into place between a failed open
        # and a look for the file would be taken for a damaged one (a spurious warning).
        return None
    found = load_entry(path, key)
    if found is None and not _warned[0]:
        _warned[0] = True
        warnings.warn(f"feature memo entry {path} is damaged, cut short, of an earlier format or of another "
                      "image; recomputed and rewritten (any further ones in this process silently)", SpmWarning)
    return found


def _store(key: bytes, value: tuple) -> OSError | None:
    """Write the entry under a temporary name, then rename it; the error, if any."""
    path = _path(key)
    tmp = path.with_name(f".{path.stem}.{socket.gethostname()}.{os.getpid()}.partial")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        save_entry(tmp, value, key)
        os.replace(tmp, path)
    except OSError as exc:
        with contextlib.suppress(OSError):
            tmp.unlink(missing_ok=True)
        return exc
    return None


def _write(key: bytes, value: tuple) -> None:
    exc = _store(key, value)
    if exc is not None:
        warnings.warn(f"cannot write the feature memo {_folder[0]} ({exc.strerror or exc}); "
                      "features are kept in memory only", SpmWarning)
        _folder[0] = None


def memoized(kind: tuple, arrays: tuple, compute: Callable[[], tuple]) -> tuple:
    """``compute()`` (a tuple of numpy arrays) for these input ``arrays``, remembered under
    ``kind``; the arrays returned are read-only (callers copy to modify)."""
    limit = budget_bytes()
    if limit <= 0:
        return compute()
    key = content_key(kind, *arrays)
    found = _entries.get(key)
    if found is not None:
        _stats["hits"] += 1
        return found
    value = _read(key) if _folder[0] is not None else None
    if value is not None:
        _stats["disk_hits"] += 1
    else:
        _stats["misses"] += 1
        value = tuple(np.asarray(v) for v in compute())
        if _folder[0] is not None:
            _write(key, value)
    for v in value:
        v.flags.writeable = False
    size = sum(v.nbytes for v in value) + 200  # the key, the tuple and the array headers
    if _stats["bytes"] + size <= limit:
        _entries[key] = value
        _stats["bytes"] += size
    return value


def memo_stats() -> dict:
    """{"entries", "bytes", "hits", "misses", "disk_hits"} of this process's memo."""
    return {"entries": len(_entries), **_stats}


def clear_memo() -> None:
    """Forget every entry in memory and reset the counts (the folder is kept)."""
    _entries.clear()
    _stats.update(bytes=0, hits=0, misses=0, disk_hits=0)

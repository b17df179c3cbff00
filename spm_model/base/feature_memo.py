"""A per-process memo of per-image features, keyed by the image's content.

Methods that extract local features inside ``fit`` and ``predict`` (N3M, SMM) see the
same images again and again in a benchmark: under ``loco`` every frame trains in five
of the six folds of each run and is tested in one, so SMM extracted SIFT about 15
times per frame and run. The memo returns the arrays computed the first time. The key is
a hash of the pixels the method was given (and the method's feature parameters), so it
knows nothing a camera would not show: it is the method's own deterministic function,
remembered, and results are identical with or without it.

Memory: each worker process keeps at most ``SPM_FEATURE_MEMO_MB`` megabytes (default
2048; 0 turns the memo off). Once full, new features are computed and not kept (an
LRU would evict every entry before its reuse when folds sweep a set larger than the
budget; keeping the first ones gives a hit rate of about budget / working set).
"""

from __future__ import annotations

import hashlib
import os
from typing import Callable

import numpy as np

DEFAULT_MB = 2048

_entries: dict[bytes, tuple] = {}
_stats = {"bytes": 0, "hits": 0, "misses": 0}


def budget_bytes() -> int:
    """The memo's size limit in bytes, from ``SPM_FEATURE_MEMO_MB`` (default 2048 MB)."""
    text = os.environ.get("SPM_FEATURE_MEMO_MB", "").strip()
    try:
        mb = float(text) if text else DEFAULT_MB
    except ValueError:
        mb = DEFAULT_MB  # a malformed setting must not stop a benchmark; the default applies
    return int(max(mb, 0.0) * 2 ** 20)


def content_key(kind: tuple, *arrays) -> bytes:
    """A 20-byte key of ``kind`` (the feature's name and parameters, reprs compared) and
    the arrays' dtypes, shapes and bytes."""
    h = hashlib.blake2b(repr(kind).encode(), digest_size=20)
    for a in arrays:
        a = np.ascontiguousarray(a)
        h.update(f"{a.dtype.str}{a.shape}".encode())
        h.update(a.data if a.size else b"")
    return h.digest()


def memoized(kind: tuple, arrays: tuple, compute: Callable[[], tuple]) -> tuple:
    """``compute()`` (a tuple of numpy arrays) for these input ``arrays``, remembered under
    ``kind``; the arrays returned from the memo are read-only (callers copy to modify)."""
    limit = budget_bytes()
    if limit <= 0:
        return compute()
    key = content_key(kind, *arrays)
    found = _entries.get(key)
    if found is not None:
        _stats["hits"] += 1
        return found
    _stats["misses"] += 1
    value = tuple(np.asarray(v) for v in compute())
    size = sum(v.nbytes for v in value) + 200  # the key, the tuple and the array headers
    if _stats["bytes"] + size <= limit:
        for v in value:
            v.flags.writeable = False
        _entries[key] = value
        _stats["bytes"] += size
    return value


def memo_stats() -> dict:
    """{"entries", "bytes", "hits", "misses"} of this process's memo."""
    return {"entries": len(_entries), **_stats}


def clear_memo() -> None:
    """Forget every entry and reset the counts."""
    _entries.clear()
    _stats.update(bytes=0, hits=0, misses=0)

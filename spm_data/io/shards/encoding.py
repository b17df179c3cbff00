"""Image chunks as HDF5's filters store them, computed by our code (zlib releases the GIL;
h5py's filters do not), and frames compressed ahead while the renderer draws the next.

The bytes are those of HDF5's shuffle, deflate level 1 and Fletcher-32 filters
(tests/io/shards/test_encoding.py compares them with HDF5's own), whichever thread
computes them.
"""

from __future__ import annotations

import sys
import zlib

import numpy as np

from spm_data.io.shards.checksums import with_fletcher32

GZIP_LEVEL = 1
# How long a compressing thread waits for the GIL before forcing a switch (Python's default:
# 5 ms) while frames are compressed ahead (ShardWriter.encode_ahead). The renderer's thread
# releases the GIL at every OpenGL call, so the threads get it without forcing; a forced
# switch makes the renderer's thread wait until the thread that asked is scheduled, which
# on a busy machine takes milliseconds, several times a frame.
AHEAD_SWITCH_INTERVAL = 0.05


def encode_chunk(frame: np.ndarray) -> bytes:
    """One frame as HDF5's filters store it: byte shuffle (multi-byte dtypes
    only), deflate level 1 (zlib format), then the Fletcher-32 checksum
    (checksums.py). Deterministic."""
    a = np.ascontiguousarray(frame)
    if a.dtype.itemsize > 1:
        a = a.view(np.uint8).reshape(-1, a.dtype.itemsize).T  # HDF5 shuffle: byte planes
    return with_fletcher32(zlib.compress(np.ascontiguousarray(a), GZIP_LEVEL))  # zlib reads the buffer: no copy


def encode_run(frames: list) -> list[bytes]:
    """encode_chunk of each frame, in order."""
    return [encode_chunk(frame) for frame in frames]


def encode_frame(frames: dict) -> dict:
    """{field: encode_chunk(frame)} of one frame's fields."""
    return {field: encode_chunk(frame) for field, frame in frames.items()}


class AheadFrame:
    """One frame's fields ({field: frame}) handed to ``pool`` to compress now; ``chunk(field)``
    gives that field's encoded chunk. A frame no thread has started when its chunks are
    needed is compressed by the caller instead of queued behind the others (the same bytes
    whoever computes them), so a caller at the end of a block never waits on a backlog."""

    def __init__(self, pool, frames: dict):
        self._frames = frames
        self._future = pool.submit(encode_frame, frames)
        self._chunks = None

    def chunk(self, field: str) -> bytes:
        if self._chunks is None:
            self._chunks = encode_frame(self._frames) if self._future.cancel() else self._future.result()
            self._frames = None
        return self._chunks[field]


class PatientSwitching:
    """Python's switch interval set to AHEAD_SWITCH_INTERVAL while frames are compressed ahead
    (a process-wide setting: ``start`` saves it, ``stop`` puts it back unless someone else
    changed it since). Changes when threads run, not what they compute."""

    def __init__(self):
        self._saved = None

    def start(self) -> None:
        if self._saved is None:
            self._saved = sys.getswitchinterval()
            sys.setswitchinterval(max(self._saved, AHEAD_SWITCH_INTERVAL))
            self._set = sys.getswitchinterval()

    def stop(self) -> None:
        if self._saved is not None:
            if sys.getswitchinterval() == self._set:
                sys.setswitchinterval(self._saved)
            self._saved = None

"""Image chunks (one frame each) as HDF5's filters store them, encoded and decoded by our
code: byte shuffle (multi-byte dtypes only), deflate level 1, Fletcher-32.

zlib releases the GIL, so a pool of threads encodes or decodes a shard's frames in
parallel where HDF5's filter pipeline (h5py holds its lock) runs on one; each thread
takes a run of ``RUN`` consecutive frames (one task per frame cost more than a small
frame's codec work). The bytes are exactly HDF5's (tests/io/shards/test_chunks.py),
whichever thread computes them. While rendering, a FramePipeline
(spm_data/pipelines/render_frames.py) compresses each frame on its threads as the renderer
draws the next.
"""

from __future__ import annotations

import zlib

import numpy as np

from spm_data.io.shards.checksums import FLETCHER32, with_fletcher32

GZIP_LEVEL = 1
DEFLATE, SHUFFLE = 1, 2  # HDF5 filter ids (H5Z_FILTER_DEFLATE, H5Z_FILTER_SHUFFLE)
RUN = 64  # frames per task on a pool
THREADS = 2  # threads of a pool (the writer's and the reader's)


def encode_chunk(frame: np.ndarray) -> bytes:
    """One frame as HDF5's filters store it: byte shuffle (multi-byte dtypes
    only), deflate level 1 (zlib format), then the Fletcher-32 checksum
    (checksums.py). Deterministic."""
    a = np.ascontiguousarray(frame)
    if a.dtype.itemsize > 1:
        a = a.view(np.uint8).reshape(-1, a.dtype.itemsize).T  # HDF5 shuffle: byte planes
    return with_fletcher32(zlib.compress(np.ascontiguousarray(a), GZIP_LEVEL))  # zlib reads the buffer: no copy


def encode_run(frames) -> list[bytes]:
    """encode_chunk of each frame, in order (one pool task)."""
    return [encode_chunk(frame) for frame in frames]


def decodable(filters: list, chunks: tuple, shape: tuple) -> bool:
    """Whether decode_chunk reads a dataset with these filter ids and chunk shape: one
    frame per chunk, deflate then Fletcher-32 (after a shuffle for multi-byte dtypes)."""
    return tuple(chunks or ()) == (1, *shape[1:]) and list(filters) in ([DEFLATE, FLETCHER32],
                                                                        [SHUFFLE, DEFLATE, FLETCHER32])


def decode_chunk(raw: bytes, dtype: np.dtype, frame_shape: tuple, shuffled: bool) -> np.ndarray | None:
    """The frame a stored chunk (payload + Fletcher-32) holds, or None when it does not
    inflate or inflates to the wrong size. The Fletcher-32 is not checked: the reader
    decodes chunks of a shard whose every byte matched its SHA-256 (seal.py)."""
    try:
        data = zlib.decompress(raw[:-4])
    except zlib.error:
        return None
    dtype = np.dtype(dtype)
    if len(data) != dtype.itemsize * int(np.prod(frame_shape, dtype=np.int64)):
        return None
    flat = np.frombuffer(data, np.uint8)
    if shuffled and dtype.itemsize > 1:
        flat = np.ascontiguousarray(flat.reshape(dtype.itemsize, -1).T)  # byte planes back to values
    return flat.view(dtype).reshape(frame_shape)


def decode_run(raws, out: np.ndarray, start: int, shuffled: bool) -> int | None:
    """Decode stored chunks into ``out[start:]``, in order (one pool task); None when all
    decoded, else the index in ``out`` of the first that failed."""
    for k, raw in enumerate(raws):
        frame = decode_chunk(raw, out.dtype, out.shape[1:], shuffled)
        if frame is None:
            return start + k
        out[start + k] = frame
    return None


def runs(n: int, per: int = RUN) -> list[range]:
    """0..n in consecutive runs of ``per`` (the last shorter)."""
    return [range(a, min(n, a + per)) for a in range(0, n, per)]

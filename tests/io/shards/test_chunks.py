"""spm_data.io.shards.chunks: frames encoded as HDF5's filters store them and decoded back,
damaged chunks refused, runs that tile the frames; our chunks are the bytes HDF5's own
filters store."""

import io
import zlib

import h5py

import numpy as np
import pytest

from spm_data.io.shards.checksums import FLETCHER32, fletcher32
from spm_data.io.shards.chunks import (DEFLATE, SHUFFLE, decodable, decode_chunk, decode_run, encode_chunk,
                                       encode_run, runs)


@pytest.mark.parametrize("dtype, shape", [("uint8", (6, 5, 3)), ("float32", (4, 7)), ("float16", (3, 2, 3))])
def test_a_frame_comes_back_from_its_chunk(dtype, shape):
    frame = (np.random.default_rng(1).random(shape) * 200).astype(dtype)
    raw = encode_chunk(frame)
    assert int.from_bytes(raw[-4:], "little") == fletcher32(raw[:-4])
    shuffled = np.dtype(dtype).itemsize > 1
    back = decode_chunk(raw, np.dtype(dtype), shape, shuffled)
    np.testing.assert_array_equal(back, frame)
    assert back.dtype == np.dtype(dtype)
    if shuffled:  # the payload holds the byte planes: first bytes of every value, then the second...
        planes = frame.view(np.uint8).reshape(-1, frame.dtype.itemsize).T.tobytes()
        assert zlib.decompress(raw[:-4]) == planes


def test_damaged_or_wrong_sized_chunks_are_none():
    frame = np.arange(12, dtype=np.uint8).reshape(3, 4)
    raw = encode_chunk(frame)
    assert decode_chunk(b"not zlib at all", np.dtype("uint8"), (3, 4), False) is None
    assert decode_chunk(raw, np.dtype("uint8"), (3, 5), False) is None  # inflates to 12 bytes, not 15
    out = np.zeros((3, 3, 4), np.uint8)
    assert decode_run([raw, raw, b"xx"], out, 0, False) == 2  # the first that failed, as an index of out
    np.testing.assert_array_equal(out[:2], [frame, frame])
    assert decode_run([raw], out, 2, False) is None and (out[2] == frame).all()


def test_runs_tile_the_frames_and_encode_run_keeps_order():
    assert [(r.start, r.stop) for r in runs(130, 64)] == [(0, 64), (64, 128), (128, 130)]
    assert runs(0) == []
    frames = np.arange(3 * 4, dtype=np.uint8).reshape(3, 2, 2)
    assert encode_run(frames) == [encode_chunk(f) for f in frames]


def test_decodable_layouts():
    assert decodable([DEFLATE, FLETCHER32], (1, 8, 8, 3), (5, 8, 8, 3))
    assert decodable([SHUFFLE, DEFLATE, FLETCHER32], (1, 8, 8), (5, 8, 8))
    assert not decodable([DEFLATE, FLETCHER32], (2, 8, 8), (5, 8, 8))  # two frames a chunk
    assert not decodable([32001, FLETCHER32], (1, 8, 8), (5, 8, 8))  # a filter we do not know


@pytest.mark.parametrize("shape, dtype", [((6, 7, 3), np.uint8), ((6, 7), np.float32), ((6, 7, 3), np.float16)])
def test_a_chunk_is_what_hdf5s_filters_store(shape, dtype):
    frames = (np.random.default_rng(1).random((2,) + shape) * 200).astype(dtype)
    buffer = io.BytesIO()
    with h5py.File(buffer, "w") as f:
        ds = f.create_dataset("x", data=frames, chunks=(1,) + shape, compression="gzip", compression_opts=1,
                              shuffle=np.dtype(dtype).itemsize > 1, fletcher32=True)
        stored = [ds.id.read_direct_chunk((i,) + (0,) * len(shape))[1] for i in range(2)]
    assert [encode_chunk(frame) for frame in frames] == stored
    assert encode_run(list(frames)) == stored



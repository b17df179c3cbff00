"""spm_data.io.shards.encoding: our chunks are the bytes HDF5's own filters store, and a
frame compressed ahead gives the same chunks whether a thread or its caller computes them."""

import io
import threading
from concurrent.futures import ThreadPoolExecutor

import h5py
import numpy as np
import pytest

from spm_data.io.shards.encoding import AheadFrame, encode_chunk, encode_frame, encode_run


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


def _frame(seed=2):
    rng = np.random.default_rng(seed)
    return {"rgb": (rng.random((5, 4, 3)) * 255).astype(np.uint8), "depth": rng.random((5, 4), dtype=np.float32)}


def test_a_frame_no_thread_has_started_is_compressed_by_its_caller():
    frame = _frame()
    release = threading.Event()
    with ThreadPoolExecutor(max_workers=1) as pool:
        pool.submit(release.wait)  # the only thread is busy: the frame stays queued
        ahead = AheadFrame(pool, frame)
        chunks = {field: ahead.chunk(field) for field in frame}  # does not wait for the thread
        assert ahead._future.cancelled()
        release.set()
    assert chunks == encode_frame(frame)
    assert chunks["depth"] == encode_chunk(frame["depth"]) and chunks["rgb"] == encode_chunk(frame["rgb"])


def test_a_frame_a_thread_has_compressed_gives_the_same_chunks():
    frame = _frame(3)
    with ThreadPoolExecutor(max_workers=1) as pool:
        ahead = AheadFrame(pool, frame)
        ahead._future.result()  # the thread has done it
        assert not ahead._future.cancelled()
        assert {field: ahead.chunk(field) for field in frame} == encode_frame(frame)


def test_the_switch_interval_is_patient_while_frames_are_compressed_ahead_and_put_back_after():
    import sys

    from spm_data.io.shards.encoding import AHEAD_SWITCH_INTERVAL, PatientSwitching

    before = sys.getswitchinterval()
    switching = PatientSwitching()
    switching.start()
    assert sys.getswitchinterval() == pytest.approx(max(before, AHEAD_SWITCH_INTERVAL))
    switching.stop()
    assert sys.getswitchinterval() == before
    switching.start()
    sys.setswitchinterval(0.001)  # someone else changed it meanwhile: theirs stays
    switching.stop()
    assert sys.getswitchinterval() == pytest.approx(0.001)
    sys.setswitchinterval(before)

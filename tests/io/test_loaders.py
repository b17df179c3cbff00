"""spm_data.io.loaders.ShardDataset: a shard folder as a map-style dataset, read lazily
per process (fork and spawn workers), verified like every other read."""

from concurrent.futures import ProcessPoolExecutor
import json
import multiprocessing
import os
import pickle
import time
import warnings

import h5py
import numpy as np
import pytest

from spm_data.errors import ShardError, SpmWarning
from spm_data.io.loaders import ShardDataset
from spm_data.io.shards import FIELDS, MANIFEST, read_shard, write_manifest, write_shard
from tests.helpers import flip_stored_byte
from tests.helpers import make_arrays as shard_arrays

COUNTS = (3, 0, 4, 2)  # frames per shard; an empty shard in the middle


def make_arrays(n, seed, h=6, w=5):
    """tests.helpers.make_arrays, with strings that also name the shard (seed)."""
    arrays = shard_arrays(n=n, h=h, w=w, seed=seed)
    for name, (dtype, _) in FIELDS.items():
        if dtype == "str":
            arrays[name] = [f"{name}-{seed}-{i}" for i in range(n)]
    return arrays


def shard_folder(out, counts):
    """``out`` made a folder of shards cup-00000.h5, ... of ``counts`` frames each, with its manifest."""
    out.mkdir()
    for k, n in enumerate(counts):
        write_shard(out / f"cup-{k:05d}.h5", make_arrays(n, seed=k), {"renderer": "test", "seed": k})
    write_manifest(out)
    return out


@pytest.fixture
def folder(tmp_path):
    return shard_folder(tmp_path / "shards", COUNTS)


def direct_read(folder, fields=None):
    """Every frame of the folder, straight from read_shard: [{field: value}]."""
    frames = []
    for path in sorted(folder.glob("*.h5")):
        whole = read_shard(path, fields)
        n = len(next(iter(whole.values())))
        frames += [{f: v[j] for f, v in whole.items()} for j in range(n)]
    return frames


def assert_item_equal(got, want):
    assert list(got) == list(want)
    for field, value in want.items():
        if isinstance(value, str):
            assert type(got[field]) is str and got[field] == value, field
        else:
            np.testing.assert_array_equal(got[field], value, err_msg=field)
            assert np.asarray(got[field]).dtype == np.asarray(value).dtype, field


def open_files() -> int:
    return len(h5py.h5f.get_obj_ids(types=h5py.h5f.OBJ_FILE))


def test_length_and_items_equal_read_shard_across_shard_boundaries(folder):
    before = open_files()
    ds = ShardDataset(folder)
    assert open_files() == before and ds._readers == {}  # nothing opened (or left open) in __init__
    want = direct_read(folder)
    assert len(ds) == sum(COUNTS) == len(want)
    assert ds.fields == tuple(FIELDS)
    for i in (0, 2, 3, 6, 7, 8, -1, -9, -3):  # 2|3 and 6|7 are shard boundaries (3 crosses the empty shard)
        assert_item_equal(ds[i], want[i])
    item = ds[0]
    assert item["rgb"].shape == (6, 5, 3) and item["rgb"].dtype == np.uint8
    assert item["K"].shape == (3, 3) and item["K"].dtype == np.float64
    assert type(item["class_name"]) is str
    assert ds.locate(3) == (2, 0) and ds.locate(-1) == (3, 1)


@pytest.mark.parametrize("index", [9, 100, -10])
def test_out_of_range_is_an_index_error(folder, index):
    with pytest.raises(IndexError, match="out of range for 9 frames"):
        ShardDataset(folder)[index]


def test_iterating_stops_at_the_end(folder):
    assert len(list(ShardDataset(folder, fields="pose"))) == 9  # the old __getitem__ protocol ends on IndexError


def test_a_subset_of_fields(folder):
    ds = ShardDataset(folder, fields=("rgb", "K", "class_name"))
    want = direct_read(folder, ["rgb", "K", "class_name"])
    for i in range(len(ds)):
        assert_item_equal(ds[i], want[i])


@pytest.mark.parametrize("fields, bad", [(("rgb", "colour"), "'colour'"), ([], "the empty list")])
def test_an_unknown_field_is_a_one_line_error(folder, fields, bad):
    with pytest.raises(ShardError) as info:
        ShardDataset(folder, fields=fields)
    message = str(info.value)
    assert "\n" not in message
    assert "expected names from spm_data.io.shards.FIELDS" in message and "visible_mask" in message
    assert "got " in message and f"fix or drop {bad}" in message


def test_an_optional_field_the_shards_lack_is_a_one_line_error(folder):
    with pytest.raises(ShardError, match=r"cup-00000.h5: shard has no field 'visible_mask' .*leave it out"):
        ShardDataset(folder, fields=["rgb", "visible_mask"])  # the first shard is verified at construction


def add_one(item):
    return {**item, "pose": item["pose"] + 1, "extra": np.int64(7)}


def test_transform_is_applied_after_reading(folder):
    ds = ShardDataset(folder, fields=["pose"], transform=add_one)
    want = direct_read(folder, ["pose"])
    for i in (0, 5, -1):
        np.testing.assert_array_equal(ds[i]["pose"], want[i]["pose"] + 1)
        assert ds[i]["extra"] == 7


def test_pickles_without_handles_and_reads_the_same(folder):
    ds = ShardDataset(folder, transform=add_one)
    first = ds[4]
    assert ds._readers  # a handle open here: pickling must drop it (h5py handles do not pickle)
    back = pickle.loads(pickle.dumps(ds))
    assert back._readers == {} and len(back) == len(ds) and back.fields == ds.fields
    assert_item_equal(back[4], first)
    ds.close()
    assert ds._readers == {}
    assert_item_equal(ds[4], first)  # reopens after close


def test_close_closes_this_process_handles(folder):
    before = open_files()
    with ShardDataset(folder) as ds:
        ds[0], ds[-1]
        assert open_files() == before + 2
    assert open_files() == before


def test_open_shards_are_bounded_least_recently_read_closed_first(folder):
    before = open_files()
    with ShardDataset(folder, max_open=2) as ds:
        want = direct_read(folder)
        for i in list(range(len(ds))) + list(range(len(ds)))[::-1]:
            assert_item_equal(ds[i], want[i])
            assert open_files() <= before + 2
        ds[0], ds[3], ds[0], ds[7]            # shards 0, 2, 0, 3: shard 2 was read least recently
        assert list(ds._readers) == [0, 3]
    with pytest.raises(ShardError, match="max_open: expected an integer >= 1"):
        ShardDataset(folder, max_open=-1)


def test_running_out_of_file_descriptors_says_so(folder):
    import resource

    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    ds = ShardDataset(folder)
    lowest_free = os.dup(0)
    os.close(lowest_free)
    try:   # no descriptor left: the first read cannot open its shard
        resource.setrlimit(resource.RLIMIT_NOFILE, (lowest_free, hard))
        with pytest.raises(ShardError,
                           match="cannot open, too many open files in this process .the limit is ulimit -n"):
            ds[0]
    finally:
        resource.setrlimit(resource.RLIMIT_NOFILE, (soft, hard))
        ds.close()
    assert_item_equal(ds[0], direct_read(folder)[0])   # and nothing else went wrong


# Pool workers: top-level functions, so spawn can import them.
_DATASET = None
# a worker that dies or hangs fails the test (BrokenProcessPool, TimeoutError), never hangs the suite
POOL_SECONDS = 240


def _pool_read(method: str, ds, n: int) -> list:
    """_read(0..n-1) in 2 worker processes started by ``method`` with ``ds`` set in each, as a
    DataLoader's workers get their dataset; in index order."""
    context = multiprocessing.get_context(method)
    with ProcessPoolExecutor(2, mp_context=context, initializer=_set_dataset, initargs=(ds,)) as pool:
        return list(pool.map(_read, range(n), timeout=POOL_SECONDS))


def _set_dataset(ds):
    global _DATASET
    _DATASET = ds


def _read(i):
    item = _DATASET[i]
    return item, os.getpid(), {shard: reader.pid for shard, reader in _DATASET._readers.items()}


@pytest.mark.parametrize("method", ["fork", "spawn"])
def test_pool_workers_read_every_item(folder, method):
    ds = ShardDataset(folder, transform=add_one)
    want = [add_one(item) for item in direct_read(folder)]
    results = _pool_read(method, ds, len(ds))
    assert len(results) == len(want)
    for (item, pid, reader_pids), expected in zip(results, want):
        assert_item_equal(item, expected)
        assert pid != os.getpid() and set(reader_pids.values()) == {pid}


def test_a_dataset_used_before_fork_reopens_in_the_children(folder):
    ds = ShardDataset(folder)
    want = direct_read(folder)
    assert_item_equal(ds[0], want[0])
    assert_item_equal(ds[-1], want[-1])
    parent_readers = dict(ds._readers)
    assert {r.pid for r in parent_readers.values()} == {os.getpid()}
    results = _pool_read("fork", ds, len(ds))
    for i, (item, pid, reader_pids) in enumerate(results):
        assert_item_equal(item, want[i])
        assert pid != os.getpid() and set(reader_pids.values()) == {pid}  # its own handles, not the parent's
    assert ds._readers == parent_readers  # the parent keeps (and uses) its own
    assert all(ds._readers[k] is r for k, r in parent_readers.items())
    assert_item_equal(ds[1], want[1])


@pytest.mark.parametrize("field", ["rgb", "K", "class_name"])
def test_a_corrupt_chunk_is_a_shard_error_naming_the_field_on_its_first_read(folder, field):
    """A shard is trusted only whole: a flipped byte in one frame's chunk refuses that shard on
    the first read of any of its frames (every byte is checked then, before a frame is returned),
    naming the field that changed; the other shards still read."""
    want = direct_read(folder)
    flip_stored_byte(folder / "cup-00002.h5", field)
    ds = ShardDataset(folder)  # shard 2 is not hashed yet: counts come from the manifest
    assert len(ds) == sum(COUNTS)
    assert_item_equal(ds[0], want[0])
    for i in (3, 6):  # the first and the last frame of shard 2
        with pytest.raises(ShardError, match=rf"cup-00002.h5: field '{field}' fails its checksum") as info:
            ds[i]
        assert "\n" not in str(info.value)
    assert_item_equal(ds[7], want[7])


THREE = (3, 4, 2)  # frames per shard of the three_shards fixture


@pytest.fixture
def three_shards(tmp_path):
    """A 3-shard folder and every frame of it read before anything is damaged: [{field: value}]."""
    out = shard_folder(tmp_path / "three", THREE)
    return out, direct_read(out)


@pytest.mark.parametrize("shard", [0, 1])  # the first shard is hashed at construction, the others on first read
def test_refuse_names_the_corrupt_shard(three_shards, shard):
    folder, _ = three_shards
    flip_stored_byte(folder / f"cup-{shard:05d}.h5", "rgb")
    with pytest.raises(ShardError) as info:
        ds = ShardDataset(folder, on_corrupt="refuse")
        [ds[i] for i in range(len(ds))]
    message = str(info.value)
    assert "\n" not in message and message.startswith(str(folder / f"cup-{shard:05d}.h5") + ":")
    assert "field 'rgb' fails its checksum" in message and "corrupt" in message


@pytest.mark.parametrize("shard", [0, 1, 2])
def test_skip_leaves_out_the_corrupt_shard_with_one_warning(three_shards, shard):
    folder, clean = three_shards
    bad = folder / f"cup-{shard:05d}.h5"
    flip_stored_byte(bad, "depth")
    with pytest.warns(SpmWarning) as caught:
        ds = ShardDataset(folder, on_corrupt="skip")
    messages = [str(w.message) for w in caught if issubclass(w.category, SpmWarning)]
    assert len(messages) == 1 and "\n" not in messages[0]
    assert messages[0].startswith(f"{bad}: field 'depth' fails its checksum") and "skipped" in messages[0]
    assert ds.skipped == (bad,) and bad not in ds.shards
    starts = np.cumsum((0,) + THREE)
    want = clean[:starts[shard]] + clean[starts[shard + 1]:]
    assert len(ds) == sum(THREE) - THREE[shard] == len(want)
    for i in range(len(ds)):
        assert_item_equal(ds[i], want[i])
    with pytest.raises(IndexError):
        ds[len(want)]


def test_skip_of_a_clean_folder_warns_nothing(three_shards):
    folder, clean = three_shards
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        ds = ShardDataset(folder, on_corrupt="skip")
    assert ds.skipped == () and len(ds) == sum(THREE)
    assert_item_equal(ds[-1], clean[-1])


@pytest.mark.parametrize("value", ["ignore", None, True])
def test_a_bad_on_corrupt_is_a_one_line_error(three_shards, value):
    with pytest.raises(ShardError) as info:
        ShardDataset(three_shards[0], on_corrupt=value)
    message = str(info.value)
    assert "\n" not in message
    assert message.startswith("ShardDataset on_corrupt: expected 'refuse' or 'skip'")
    assert f"got {value!r}" in message and "pass on_corrupt='refuse'" in message


def test_a_manifest_count_the_shard_does_not_match_is_an_error_on_first_read(three_shards):
    folder, clean = three_shards
    manifest = json.loads((folder / MANIFEST).read_text())
    manifest["shards"][1]["frames"] += 1
    (folder / MANIFEST).write_text(json.dumps(manifest))
    ds = ShardDataset(folder)
    assert len(ds) == sum(THREE) + 1
    assert_item_equal(ds[0], clean[0])
    with pytest.raises(ShardError, match=r"cup-00001.h5: 4 frames in the shard, manifest.json says 5"):
        ds[3]


def test_manifest_rules_apply(folder):
    (folder / MANIFEST).unlink()
    with pytest.raises(ShardError, match="no manifest.json"):
        ShardDataset(folder)
    with pytest.warns(UserWarning, match="allow-partial"):
        ds = ShardDataset(folder, allow_partial=True)
    assert len(ds) == sum(COUNTS)


def test_a_single_shard_file(folder):
    ds = ShardDataset(folder / "cup-00002.h5", fields=["t"])
    assert len(ds) == 4
    np.testing.assert_array_equal(ds[-1]["t"], read_shard(folder / "cup-00002.h5", ["t"])["t"][3])


# Forked workers made anew each epoch (DataLoader without persistent_workers): a shard one of
# them verified is not hashed again by the next epoch's workers.
_HASHES = multiprocessing.Value("i", 0)


def _counting_digest(real):
    def digest(path):
        with _HASHES.get_lock():
            _HASHES.value += 1
        return real(path)
    return digest


def test_workers_forked_each_epoch_hash_each_shard_once_per_run(folder, monkeypatch):
    from spm_data.io.shards import forget_checks, seal
    from tests.helpers import wait_for

    newest = max(p.stat().st_ctime for p in folder.glob("*.h5"))
    wait_for(lambda: time.time() - newest > seal.RACY_SECONDS, "the shards' ctime older than RACY_SECONDS")
    want = direct_read(folder, ["pose", "class_name"])
    forget_checks()  # as a fresh training run starts: nothing verified in this process
    monkeypatch.setattr(seal, "content_digest", _counting_digest(seal.content_digest))
    ds = ShardDataset(folder, fields=["pose", "class_name"])
    hashes = []
    for epoch in range(3):
        _HASHES.value = 0
        results = _pool_read("fork", ds, len(ds))
        for (item, _, _), expected in zip(results, want):
            assert_item_equal(item, expected)
        hashes.append(_HASHES.value)
    assert hashes[0] <= 2 * 3 and hashes[1:] == [0, 0]  # 3 non-empty shards, 2 workers; none again later


def test_a_shared_record_held_by_a_stopped_process_is_done_without_not_waited_for(folder, monkeypatch):
    """A worker killed inside the shared record's lock leaves it held: readers wait LOCK_SECONDS,
    then verify the shard themselves (the same items), and never hang."""
    import threading

    from spm_data.io.loaders import _SharedChecks
    from spm_data.io.shards import forget_checks

    monkeypatch.setattr(_SharedChecks, "LOCK_SECONDS", 0.05)
    ds = ShardDataset(folder)
    want = direct_read(folder)
    held, done = threading.Event(), threading.Event()

    def stopped_worker():   # takes the lock and never gives it back while the test reads
        lock = ds._checks._memory.get_lock()
        lock.acquire()
        held.set()
        done.wait()
        lock.release()

    thread = threading.Thread(target=stopped_worker, daemon=True)
    thread.start()
    held.wait()
    got = []
    forget_checks()   # nothing verified in this process: every shard's record is asked for
    reader = threading.Thread(target=lambda: got.extend(ds[i] for i in range(len(ds))), daemon=True)
    reader.start()
    reader.join(timeout=60)   # a reader that waits for the lock for ever fails here instead of hanging
    finished = not reader.is_alive()
    done.set()
    thread.join()
    assert finished and len(got) == len(want)
    for item, expected in zip(got, want):
        assert_item_equal(item, expected)

"""spm_data.io.shards.writer: write_shard writes every field whole and checksummed, the same
bytes for the same arrays, and leaves the old shard in place when a write fails."""

import h5py
import numpy as np
import pytest

from spm_data.errors import ShardError
from spm_data.io.files import file_sha256
from spm_data.io.shards import FIELDS, IMAGE_FIELDS, SCHEMA_VERSION, list_shards, read_attrs, read_shard, write_shard
from spm_data.io.shards.writer import ShardWriter
from tests.helpers import make_arrays


def test_round_trip_preserves_every_field(tmp_path):
    arrays = make_arrays()
    path = write_shard(tmp_path / "a.h5", arrays, {"renderer": "test", "seed": 4, "spec": "x = 1"})
    back = read_shard(path)
    for name, value in arrays.items():
        if FIELDS[name][0] == "str":
            assert list(back[name]) == value
        else:
            np.testing.assert_array_equal(back[name], value)
            assert back[name].dtype == np.dtype(FIELDS[name][0])
    attrs = read_attrs(path)
    assert attrs["schema_version"] == SCHEMA_VERSION and attrs["frames"] == 3 and attrs["seed"] == 4
    with h5py.File(path) as f:
        assert f["rgb"].chunks == (1, 8, 10, 3) and f["rgb"].compression is not None
    assert list_shards(tmp_path) == [path]


def test_same_arrays_give_identical_bytes(tmp_path):
    a = write_shard(tmp_path / "a.h5", make_arrays(), {"seed": 1, "renderer": "x"})
    b = write_shard(tmp_path / "b.h5", make_arrays(), {"seed": 1, "renderer": "x"})
    assert file_sha256(a) == file_sha256(b)


def test_frames_prepared_ahead_give_the_same_bytes(tmp_path):
    """occlude hands frames to prepare before it stores them: the shard is the same bytes as
    without, whichever frames were prepared ahead and in whatever order."""
    arrays = make_arrays(n=5, seed=4)
    images = [f for f in IMAGE_FIELDS if f in arrays]
    labels = {f: v for f, v in arrays.items() if f not in images}

    def write(path, ahead=()):
        with ShardWriter(path, frames=5, height=8, width=10, images=images) as writer:
            for i in ahead:
                writer.prepare(i, {f: arrays[f][i:i + 1] for f in images})
            writer.write_images(0, {f: arrays[f][:2] for f in images})
            writer.write_images(2, {f: arrays[f][2:] for f in images})
            return writer.finish(labels, {"seed": 1, "renderer": "x"})

    plain = write(tmp_path / "plain.h5")
    assert file_sha256(write(tmp_path / "ahead.h5", ahead=(3, 0, 4))) == file_sha256(plain)  # 1, 2: not ahead
    assert file_sha256(write(tmp_path / "all.h5", ahead=range(5))) == file_sha256(plain)
    np.testing.assert_array_equal(read_shard(plain)["depth"], arrays["depth"])


def test_compression_runs_give_the_same_bytes(tmp_path, monkeypatch):
    """write_images compresses the frames not prepared ahead in runs of RUN frames; runs
    that straddle a frame prepared ahead still store every chunk in order."""
    arrays = make_arrays(n=5, seed=5)
    images = [f for f in IMAGE_FIELDS if f in arrays]
    labels = {f: v for f, v in arrays.items() if f not in images}
    plain = write_shard(tmp_path / "plain.h5", arrays, {"seed": 1, "renderer": "x"})
    monkeypatch.setattr("spm_data.io.shards.writer.RUN", 2)
    with ShardWriter(tmp_path / "runs.h5", frames=5, height=8, width=10, images=images) as writer:
        writer.prepare(2, {f: arrays[f][2:3] for f in images})  # runs: frames 0-1 and 3-4 of each field
        writer.write_images(0, {f: arrays[f] for f in images})
        runs = writer.finish(labels, {"seed": 1, "renderer": "x"})
    assert file_sha256(runs) == file_sha256(plain)


def test_failed_write_leaves_no_partial_and_keeps_the_old_shard(tmp_path, monkeypatch):
    good = write_shard(tmp_path / "a.h5", make_arrays(seed=1), {"seed": 1, "renderer": "x"})
    before = file_sha256(good)

    def no_space(*args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr("os.fsync", no_space)
    with pytest.raises(ShardError, match="could not write shard .*a.h5: No space left on device"):
        write_shard(tmp_path / "a.h5", make_arrays(seed=2), {"seed": 2, "renderer": "x"})
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.h5"]
    assert file_sha256(good) == before


def test_our_chunks_read_back_through_hdf5s_own_filters(tmp_path):
    arrays = make_arrays(n=6, h=12, w=9, seed=3)
    path = write_shard(tmp_path / "a.h5", arrays, {"seed": 0, "renderer": "x"})
    with h5py.File(path) as f:  # the library's filter pipeline decodes what encode_chunk wrote
        for name in ("rgb", "depth", "mask"):
            np.testing.assert_array_equal(f[name][:], arrays[name])
            assert f[name].compression == "gzip" and f[name].shuffle == (f[name].dtype.itemsize > 1)


def test_a_failed_write_is_said_in_a_few_words_not_hdf5_text():
    from spm_data.io.shards.writer import write_failure

    hdf5 = ("Unable to synchronously copy object (unable to write to file: time = Mon Nov 23 10:00:00 2026, "
            "filename = 'x.h5', file descriptor = 5, errno = 28, error message = 'No space left on device')")
    assert write_failure(RuntimeError(hdf5)) == "No space left on device"
    assert write_failure(OSError(28, "No space left on device")) == "No space left on device"
    assert write_failure(RuntimeError("something\nelse")) == "something else"


def test_chunks_stored_one_at_a_time_in_write_images_order_are_its_bytes(tmp_path):
    """render_shard's pipeline casts each frame (check_frame: float32 normals are stored as
    float16), encodes it and stores the chunks one at a time (store_chunk) in the order
    write_images stores a block, field by field: the same bytes as write_images of the same
    blocks, and for one block the same as write_shard."""
    from spm_data.io.shards.chunks import encode_chunk

    arrays = make_arrays(n=5, seed=6)
    images = [f for f in IMAGE_FIELDS if f in arrays] + ["normals"]
    normals = np.random.default_rng(6).normal(size=(5, 8, 10, 3)).astype(np.float32)
    arrays["normals"] = normals.astype(np.float16)
    labels = {f: v for f, v in arrays.items() if f not in images}

    def write(path, blocks, one_at_a_time):
        with ShardWriter(path, frames=5, height=8, width=10, images=images) as writer:
            for start, stop in blocks:
                if not one_at_a_time:
                    writer.write_images(start, {f: arrays[f][start:stop] for f in images})
                    continue
                for field in images:
                    for i in range(start, stop):
                        frame = normals[i] if field == "normals" else arrays[field][i]
                        writer.store_chunk(field, i, encode_chunk(writer.check_frame(field, frame)))
            return writer.finish(labels, {"seed": 1, "renderer": "x"})

    blocks = ((0, 3), (3, 5))
    assert file_sha256(write(tmp_path / "a.h5", blocks, True)) == file_sha256(write(tmp_path / "i.h5", blocks, False))
    one = write_shard(tmp_path / "one.h5", arrays, {"seed": 1, "renderer": "x"})
    assert file_sha256(write(tmp_path / "a1.h5", [(0, 5)], True)) == file_sha256(one)
    np.testing.assert_array_equal(read_shard(one)["normals"], normals.astype(np.float16))


def test_check_frame_refuses_a_wrong_shape_or_field_and_a_short_shard_is_not_written(tmp_path):
    from spm_data.io.shards.chunks import encode_chunk

    arrays = make_arrays(n=2)
    images = [f for f in IMAGE_FIELDS if f in arrays]
    with ShardWriter(tmp_path / "a.h5", frames=2, height=8, width=10, images=images) as writer:
        with pytest.raises(ShardError, match=r"^shard field 'rgb': expected a frame of \(8, 10, 3\), got \(8, 9, 3\)$"):
            writer.check_frame("rgb", arrays["rgb"][0][:, :9])
        with pytest.raises(ShardError, match=r"^shard field 'normals': not an image field of this shard"):
            writer.check_frame("normals", np.zeros((8, 10, 3)))
        for field in images:
            writer.store_chunk(field, 0, encode_chunk(writer.check_frame(field, arrays[field][0])))
        with pytest.raises(ShardError, match=r"a\.h5: incomplete shard \(rgb, depth, mask\); not written"):
            writer.finish({f: v for f, v in arrays.items() if f not in images}, {"seed": 1})
    assert list(tmp_path.iterdir()) == []  # nothing left behind


def test_a_finished_writer_knows_its_manifest_entry(tmp_path):
    from spm_data.io.shards import manifest_entry

    arrays = make_arrays(n=3)
    arrays["class_name"] = ["cup", "box", "cup"]
    images = [f for f in IMAGE_FIELDS if f in arrays]
    with ShardWriter(tmp_path / "a.h5", frames=3, height=8, width=10, images=images) as writer:
        writer.write_images(0, {f: arrays[f] for f in images})
        path = writer.finish({f: v for f, v in arrays.items() if f not in images}, {"seed": 1, "renderer": "x"})
    entry = manifest_entry(path, writer.written)
    assert entry == manifest_entry(path)  # the same row as reading the shard back
    assert entry["classes"] == {"box": 1, "cup": 2} and entry["frames"] == 3 and entry["renderer"] == "x"

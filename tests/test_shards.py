import json

import h5py
import numpy as np
import pytest

from spm_data.errors import ShardError
from spm_data.io.files import file_sha256
from spm_data.io.shards import FIELDS, SCHEMA_VERSION, list_shards, read_attrs, read_manifest, read_shard, write_manifest, write_shard


def make_arrays(n=3, h=8, w=10, seed=0):
    rng = np.random.default_rng(seed)
    arrays = {}
    for name, (dtype, shape) in FIELDS.items():
        shape = (n,) + tuple({"H": h, "W": w, "R": 1}.get(d, d) for d in shape)
        if dtype == "str":
            arrays[name] = [f"{name}-{i}" for i in range(n)]
        elif dtype == "bool":
            arrays[name] = rng.random(shape) > 0.5
        else:
            arrays[name] = (rng.random(shape) * 100).astype(dtype)
    return arrays


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


def test_frame_selection(tmp_path):
    arrays = make_arrays(n=5)
    path = write_shard(tmp_path / "a.h5", arrays, {"seed": 0, "renderer": "x"})
    got = read_shard(path, ["pose", "class_name"], frames=np.array([1, 3]))
    np.testing.assert_array_equal(got["pose"], arrays["pose"][[1, 3]])
    assert list(got["class_name"]) == ["class_name-1", "class_name-3"]


@pytest.mark.parametrize("mutate, message", [
    (lambda a: a.pop("mask"), "missing mask"),
    (lambda a: a.update(depth=a["depth"].astype(np.float64)), "expected dtype float32"),
    (lambda a: a.update(R=a["R"][:, :2]), "'R': expected shape"),
    (lambda a: a.update(extra=np.zeros(3)), "unknown fields extra"),
])
def test_bad_arrays_are_refused_and_nothing_is_written(tmp_path, mutate, message):
    arrays = make_arrays()
    mutate(arrays)
    with pytest.raises(ShardError, match=message):
        write_shard(tmp_path / "a.h5", arrays, {})
    assert list(tmp_path.iterdir()) == []


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


def test_newer_schema_and_foreign_files_are_refused(tmp_path):
    path = write_shard(tmp_path / "a.h5", make_arrays(), {"seed": 0, "renderer": "x"})
    with h5py.File(path, "a") as f:
        f.attrs["schema_version"] = SCHEMA_VERSION + 1
    with pytest.raises(ShardError, match="newer than this spm"):
        read_shard(path)
    (tmp_path / "b.h5").write_bytes(b"not hdf5")
    with pytest.raises(ShardError, match="not a readable HDF5 shard"):
        read_attrs(tmp_path / "b.h5")
    with h5py.File(tmp_path / "c.h5", "w") as f:
        f["x"] = 1
    with pytest.raises(ShardError, match="not an spm shard"):
        read_attrs(tmp_path / "c.h5")


def test_manifest_lists_shards_with_counts_and_checksums(tmp_path):
    a = make_arrays(n=3)
    a["class_name"] = ["cup", "cup", "box"]
    write_shard(tmp_path / "s0.h5", a, {"seed": 0, "renderer": "x"})
    write_shard(tmp_path / "s1.h5", make_arrays(n=2), {"seed": 0, "renderer": "x"})
    (tmp_path / ".s2.h5.partial").write_bytes(b"half")
    payload = write_manifest(tmp_path)
    on_disk = read_manifest(tmp_path)
    assert payload == on_disk
    assert [e["file"] for e in on_disk["shards"]] == ["s0.h5", "s1.h5"]
    assert on_disk["frames"] == 5
    assert on_disk["classes"] == {"box": 1, "class_name-0": 1, "class_name-1": 1, "cup": 2}
    assert on_disk["shards"][0]["sha256"] == file_sha256(tmp_path / "s0.h5")
    json.loads((tmp_path / "manifest.json").read_text())


def test_our_chunks_read_back_through_hdf5s_own_filters(tmp_path):
    arrays = make_arrays(n=6, h=12, w=9, seed=3)
    path = write_shard(tmp_path / "a.h5", arrays, {"seed": 0, "renderer": "x"})
    with h5py.File(path) as f:  # the library's filter pipeline decodes what encode_chunk wrote
        for name in ("rgb", "depth", "mask"):
            np.testing.assert_array_equal(f[name][:], arrays[name])
            assert f[name].compression == "gzip" and f[name].shuffle == (f[name].dtype.itemsize > 1)


def test_corrupt_chunk_is_a_shard_error(tmp_path):
    path = write_shard(tmp_path / "a.h5", make_arrays(n=2, h=40, w=40), {"seed": 0, "renderer": "x"})
    with h5py.File(path, "a") as f:
        f["depth"].id.write_direct_chunk((1, 0, 0), b"not zlib at all")
    with pytest.raises(ShardError, match="field 'depth' fails its checksum"):
        read_shard(path, ["depth"])

"""spm_data.io.shards.reader: frame selection, and every read verified (schema version,
foreign files, corrupt chunks are ShardErrors naming the shard)."""

import h5py
import numpy as np
import pytest

from spm_data.errors import ShardError
from spm_data.io.shards import SCHEMA_VERSION, ShardReader, read_attrs, read_shard, shard_digest, write_shard
from spm_data.io.shards.seal import USERBLOCK, content_digest
from tests.helpers import make_arrays


def test_frame_selection(tmp_path):
    arrays = make_arrays(n=5)
    path = write_shard(tmp_path / "a.h5", arrays, {"seed": 0, "renderer": "x"})
    got = read_shard(path, ["pose", "class_name"], frames=np.array([1, 3]))
    np.testing.assert_array_equal(got["pose"], arrays["pose"][[1, 3]])
    assert list(got["class_name"]) == ["class_name-1", "class_name-3"]


def test_newer_schema_and_foreign_files_are_refused(tmp_path):
    path = write_shard(tmp_path / "a.h5", make_arrays(), {"seed": 0, "renderer": "x"})
    with h5py.File(path, "a") as f:
        f.attrs["schema_version"] = SCHEMA_VERSION + 1
    with pytest.raises(ShardError, match="newer than this spm"):
        read_shard(path)
    (tmp_path / "b.h5").write_bytes(b"not hdf5")
    with pytest.raises(ShardError, match="b.h5: not an spm shard: it does not start with spm's header"):
        read_attrs(tmp_path / "b.h5")
    with h5py.File(tmp_path / "c.h5", "w") as f:
        f["x"] = 1
    with pytest.raises(ShardError, match="not an spm shard"):
        read_attrs(tmp_path / "c.h5")


def test_corrupt_chunk_is_a_shard_error(tmp_path):
    path = write_shard(tmp_path / "a.h5", make_arrays(n=2, h=40, w=40), {"seed": 0, "renderer": "x"})
    with h5py.File(path, "a") as f:
        f["depth"].id.write_direct_chunk((1, 0, 0), b"not zlib at all")
    with pytest.raises(ShardError, match="field 'depth' fails its checksum"):
        read_shard(path, ["depth"])


def flip(path, at, bit=0):
    data = bytearray(path.read_bytes())
    data[at] ^= 1 << bit
    path.write_bytes(bytes(data))


def test_every_byte_is_covered_by_the_header(tmp_path):
    """The header names the SHA-256 of every byte after it; a flip anywhere (the header,
    HDF5's superblock and object headers, a chunk) is refused before HDF5 reads it."""
    arrays = make_arrays(n=2)
    path = write_shard(tmp_path / "a.h5", arrays, {"seed": 0, "renderer": "x"})
    data = path.read_bytes()
    assert data.startswith(b"spm-shard sha256=" + content_digest(path).encode() + b"\n")
    assert data[USERBLOCK:USERBLOCK + 8] == b"\x89HDF\r\n\x1a\n" and shard_digest(path) == content_digest(path)
    for at, found in [(20, ""),  # a digit of the digest: damaged header or a digest that differs
                      (400, "its checksum header (the first 512 bytes) is damaged; the shard is corrupt"),
                      (USERBLOCK + 9, ""),  # HDF5's superblock
                      (len(data) - 1, "")]:
        bad = tmp_path / f"bad-{at}.h5"
        bad.write_bytes(data)
        flip(bad, at)
        with pytest.raises(ShardError) as info:
            read_shard(bad, ["pose"])
        assert str(info.value).startswith(f"{bad}: ") and found in str(info.value)
        assert "corrupt" in str(info.value) or "not a readable HDF5 shard" in str(info.value)


def test_verified_once_per_process_while_unchanged(tmp_path, monkeypatch):
    """A file is hashed on its first open; later opens of the same unchanged file (device,
    inode, size, mtime, ctime) are not, unless its ctime was too recent to tell a change
    within the clock's tick (git's racy-clean rule). A replaced file is hashed again."""
    import time

    from spm_data.io.shards import seal

    hashed = []
    monkeypatch.setattr(seal, "content_digest", lambda path: hashed.append(path) or content_digest(path))
    path = write_shard(tmp_path / "a.h5", make_arrays(n=2), {"seed": 0, "renderer": "x"})
    hashed.clear()  # the writer's seal
    read_shard(path, ["pose"]), read_shard(path, ["pose"])
    assert len(hashed) == 2  # written just now: racy, so hashed on each open
    hashed.clear()
    later = time.time() + 2 * seal.RACY_SECONDS
    monkeypatch.setattr(seal.time, "time", lambda: later)
    read_shard(path, ["pose"]), read_shard(path, ["pose"]), ShardReader(path).close()
    assert len(hashed) == 1
    bad = tmp_path / "bad.h5"
    bad.write_bytes(path.read_bytes())
    flip(bad, USERBLOCK + 9)
    bad.replace(path)
    with pytest.raises(ShardError, match="a.h5: (not a readable HDF5 shard|.*corrupt)"):
        read_shard(path, ["pose"])
    assert len(hashed) == 2


def test_a_request_h5py_cannot_serve_is_not_called_corruption(tmp_path):
    path = write_shard(tmp_path / "a.h5", make_arrays(n=4), {"seed": 0, "renderer": "x"})
    with ShardReader(path) as reader, pytest.raises(ShardError) as info:
        reader.read(["pose"], frames=np.array([2, 2]))
    assert "cannot read field 'pose' for frames [2, 2]" in str(info.value) and "corrupt" not in str(info.value)


def test_an_old_shard_without_a_header_is_refused_with_what_to_do(tmp_path):
    with h5py.File(tmp_path / "old.h5", "w") as f:
        f.attrs["schema_version"] = 2
    with pytest.raises(ShardError, match="without spm's whole-file checksum .* make it again with this spm"):
        read_attrs(tmp_path / "old.h5")


def test_image_fields_decoded_by_spm_equal_hdf5s_own_decoding(tmp_path):
    """read (whole fields, slices) and read_runs decode the stored chunks on threads: the same
    arrays as HDF5's filter pipeline gives."""
    arrays = make_arrays(n=70, h=6, w=5)  # more than one run of chunks.RUN frames
    path = write_shard(tmp_path / "a.h5", arrays, {"seed": 0, "renderer": "x"})
    with h5py.File(path, "r") as f:
        by_hdf5 = {name: f[name][...] for name in ("rgb", "depth", "mask")}
    with ShardReader(path) as reader:
        for name, value in by_hdf5.items():
            np.testing.assert_array_equal(reader.read([name])[name], value)
            np.testing.assert_array_equal(reader.read([name], frames=slice(3, 67, 2))[name], value[3:67:2])
            got = reader.read_runs(name)
            assert [(run.start, run.stop) for run, _ in got] == [(0, 64), (64, 70)]
            np.testing.assert_array_equal(np.concatenate([get() for _, get in got]), value)
        assert reader.layout()["depth"] == ((70, 6, 5), "float32")


def test_attributes_are_checked_once_per_content(tmp_path, monkeypatch):
    """Opening a shard hashes it (once per process while unchanged) and checks its attributes
    and layout once per content digest."""
    import spm_data.io.shards.reader as reader_module
    from spm_data.io.shards import forget_checks

    path = write_shard(tmp_path / "a.h5", make_arrays(), {"seed": 0, "renderer": "x"})
    forget_checks()
    calls = []
    real = reader_module.checksum_mismatch
    monkeypatch.setattr(reader_module, "checksum_mismatch", lambda f: calls.append(1) or real(f))
    for _ in range(3):
        assert read_attrs(path)["seed"] == 0
    assert len(calls) == 1
    forget_checks()
    read_attrs(path)
    assert len(calls) == 2

"""spm_data.io.shards.reader: frame selection, and every read verified (schema version,
foreign files, corrupt chunks are ShardErrors naming the shard)."""

import h5py
import numpy as np
import pytest

from spm_data.errors import ShardError
from spm_data.io.shards import SCHEMA_VERSION, read_attrs, read_shard, write_shard
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
    with pytest.raises(ShardError, match="not a readable HDF5 shard"):
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

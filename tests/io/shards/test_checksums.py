"""spm_data.io.shards.checksums: Fletcher-32 exactly as HDF5 computes it, and the CRC-32s
of attributes and layouts that name what changed."""

import json

import h5py
import numpy as np
import pytest

from spm_data.io.shards import write_shard
from spm_data.io.shards.checksums import (CHECKSUMS_ATTR, checksum_mismatch, file_checksums, fletcher32, item_crc,
                                          stored_chunk_ok, with_fletcher32)
from tests.helpers import make_arrays


def test_fletcher32_of_known_bytes():
    assert fletcher32(b"") == 0
    assert fletcher32(b"\x00\x01") == (1 << 16) | 1               # one word 1: both sums 1
    # Words 0x0102, 0x0300 (the odd last byte padded): s1 = 0x0402, s2 = 2 * 0x0102 + 0x0300 = 0x0504.
    assert fletcher32(b"\x01\x02\x03") == (0x0504 << 16) | 0x0402
    assert fletcher32(b"\xff\xff\x00\x01") == (0x0001 << 16) | 0x0001  # 0xFFFF + 1 folds to 1


def _bytes(size):
    return np.random.default_rng(size).integers(0, 256, size, dtype=np.uint8).tobytes()


@pytest.mark.parametrize("data", [_bytes(1), _bytes(2), _bytes(7), _bytes(64), _bytes(4099), b"\x00\x00",
                                  b"\xff\xff", b"\xff\xff\x00\x00", b"\x00\x01\xff\xfe"],
                         ids=["1", "2", "7", "64", "4099", "zeros", "ffff", "ffff-0000", "sum-65535"])
def test_fletcher32_matches_what_hdf5_stores(tmp_path, data):
    size = len(data)
    data = np.frombuffer(data, np.uint8)
    with h5py.File(tmp_path / "f.h5", "w") as f:
        f.create_dataset("x", data=data, chunks=(size,), fletcher32=True)
    with h5py.File(tmp_path / "f.h5", "r") as f:
        _, raw = f["x"].id.read_direct_chunk((0,))
    assert raw[:-4] == data.tobytes()
    assert int.from_bytes(raw[-4:], "little") == fletcher32(data.tobytes())
    assert with_fletcher32(data.tobytes()) == raw and stored_chunk_ok(raw)
    flipped = bytearray(raw)
    flipped[0] ^= 0x01
    assert not stored_chunk_ok(bytes(flipped)) and not stored_chunk_ok(b"abc")


@pytest.mark.parametrize("data", [_bytes(4099), b"\xff\xff" * 5000, b"\xff" * 3001, _bytes(1 << 20)],
                         ids=["random", "ffff-words", "odd-ff", "1MiB"])
def test_fletcher32_plain_sums_equal_the_reduced_ones(monkeypatch, data):
    """Chunks up to _EXACT_WORDS words are summed plainly in int64 and reduced once; the
    same value as reducing every term (the path longer chunks take)."""
    fast = fletcher32(data)
    monkeypatch.setattr("spm_data.io.shards.checksums._EXACT_WORDS", 0)
    assert fletcher32(data) == fast


def test_item_crc_is_canonical():
    assert item_crc({"a": 1, "b": [1, 2]}) == item_crc({"b": [1, 2], "a": 1})
    assert item_crc(b"spec") == item_crc("spec") and item_crc(np.arange(3)) == item_crc([0, 1, 2])
    assert item_crc(np.int64(4)) == item_crc(4) and item_crc(4) != item_crc(5)


def test_checksum_mismatch_names_the_changed_item(tmp_path):
    path = write_shard(tmp_path / "a.h5", make_arrays(), {"seed": 1, "renderer": "x"})
    with h5py.File(path, "r") as f:
        assert checksum_mismatch(f) is None
        sums = file_checksums(f)
        assert "seed" in sums["attrs"] and CHECKSUMS_ATTR not in sums["attrs"] and "rgb" in sums["layout"]
    with h5py.File(path, "a") as f:
        f.attrs["seed"] = 2
    with h5py.File(path, "r") as f:
        assert checksum_mismatch(f) == "attribute 'seed' fails its checksum"
    with h5py.File(path, "a") as f:
        f.attrs["seed"] = 1
        f.attrs["extra"] = "x"
    with h5py.File(path, "r") as f:
        assert checksum_mismatch(f) == "attribute 'extra' was added after writing"
    with h5py.File(path, "a") as f:
        del f.attrs["extra"]
        del f.attrs[CHECKSUMS_ATTR]
    with h5py.File(path, "r") as f:
        assert checksum_mismatch(f) == "no readable checksums attribute"


def test_a_changed_checksums_attribute_is_named_not_the_item_it_covers(tmp_path):
    path = write_shard(tmp_path / "a.h5", make_arrays(), {"seed": 1, "renderer": "x"})
    with h5py.File(path, "a") as f:
        sums = json.loads(f.attrs[CHECKSUMS_ATTR])
        sums["attrs"]["seed"] += 1
        f.attrs[CHECKSUMS_ATTR] = json.dumps(sums)
    with h5py.File(path, "r") as f:
        assert checksum_mismatch(f) == "attribute 'checksums' fails its own checksum"

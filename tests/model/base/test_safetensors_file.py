import json
import struct

import numpy as np
import pytest

from spm_model.base.safetensors_file import read_safetensors, write_safetensors


def test_arrays_round_trip_with_their_dtypes_shapes_and_metadata(tmp_path):
    arrays = {"w": np.arange(12, dtype=np.float32).reshape(3, 4), "count": np.array(7, dtype=np.int64),
              "poses": np.linspace(0, 1, 6).reshape(1, 6), "flags": np.array([True, False])}
    path = write_safetensors(tmp_path / "m.safetensors", arrays, {"kind": "test", "params": {"side": 32}})
    back, metadata = read_safetensors(path)
    assert list(back) == list(arrays) and metadata == {"kind": "test", "params": '{"side": 32}'}
    for name, value in arrays.items():
        assert back[name].dtype == value.dtype and back[name].shape == value.shape
        assert np.array_equal(back[name], value)


def test_the_layout_is_the_formats_header_length_json_and_aligned_little_endian_bytes(tmp_path):
    path = write_safetensors(tmp_path / "m.safetensors", {"a": np.array([1.0, 2.0], np.float64),
                                                          "b": np.array([[3]], np.int32)})
    data = path.read_bytes()
    (n,) = struct.unpack("<Q", data[:8])
    header = json.loads(data[8: 8 + n])
    assert n % 8 == 0 and header == {"a": {"dtype": "F64", "shape": [2], "data_offsets": [0, 16]},
                                     "b": {"dtype": "I32", "shape": [1, 1], "data_offsets": [16, 20]}}
    assert data[8 + n:] == struct.pack("<2d", 1.0, 2.0) + struct.pack("<i", 3)
    assert not list(tmp_path.glob(".*partial"))                       # written whole, then renamed


def test_a_dtype_the_format_lacks_is_refused_and_nothing_is_written(tmp_path):
    with pytest.raises(ValueError, match="safetensors: c has dtype complex128"):
        write_safetensors(tmp_path / "m.safetensors", {"c": np.zeros(2, complex)})
    assert not (tmp_path / "m.safetensors").exists()

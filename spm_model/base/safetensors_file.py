"""Arrays as a safetensors file, written and read with numpy alone (no dependency).

The format (https://github.com/huggingface/safetensors, "Format"): 8 bytes, the length N of
the header as a little-endian unsigned 64-bit integer; N bytes of JSON, {name: {"dtype",
"shape", "data_offsets": [begin, end]}} plus an optional "__metadata__" of string values,
padded with spaces to a multiple of 8; then the tensors' little-endian C-order bytes, each at
its offsets from the end of the header. ``safetensors.numpy.load_file`` and
``safetensors.torch.load_file`` read what ``write_safetensors`` writes.
"""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np

from spm_data.io.files import atomic_file

DTYPES = {"float64": "F64", "float32": "F32", "float16": "F16", "int64": "I64", "int32": "I32",
          "int16": "I16", "int8": "I8", "uint8": "U8", "bool": "BOOL"}


def write_safetensors(path, arrays: dict, metadata: dict | None = None) -> Path:
    """Write {name: array} (dtypes of DTYPES) to ``path`` as safetensors, atomically; ``metadata``
    values that are not strings are stored as JSON text. Returns the path."""
    header, blobs, offset = {}, [], 0
    for name, value in arrays.items():
        a = np.asarray(value)   # not ascontiguousarray, which makes a 0-d array 1-d
        if a.dtype.name not in DTYPES:
            raise ValueError(f"safetensors: {name} has dtype {a.dtype}, not one of {sorted(DTYPES)}")
        blob = a.astype(a.dtype.newbyteorder("<"), copy=False).tobytes(order="C")
        header[name] = {"dtype": DTYPES[a.dtype.name], "shape": list(a.shape),
                        "data_offsets": [offset, offset + len(blob)]}
        blobs.append(blob)
        offset += len(blob)
    if metadata:
        header["__metadata__"] = {k: v if isinstance(v, str) else json.dumps(v) for k, v in metadata.items()}
    text = json.dumps(header, separators=(",", ":")).encode()
    text += b" " * (-len(text) % 8)
    path = Path(path)
    with atomic_file(path) as tmp, open(tmp, "wb") as out:
        out.write(struct.pack("<Q", len(text)))
        out.write(text)
        for blob in blobs:
            out.write(blob)
    return path


def read_safetensors(path) -> tuple[dict, dict]:
    """({name: array}, metadata) of a safetensors file (the reverse of write_safetensors)."""
    data = Path(path).read_bytes()
    (n,) = struct.unpack("<Q", data[:8])
    header = json.loads(data[8: 8 + n])
    metadata = header.pop("__metadata__", {})
    names = {v: k for k, v in DTYPES.items()}
    arrays = {}
    for name, info in header.items():
        begin, end = info["data_offsets"]
        dtype = np.dtype(names[info["dtype"]]).newbyteorder("<")
        arrays[name] = np.frombuffer(data[8 + n + begin: 8 + n + end], dtype=dtype).reshape(tuple(info["shape"]))
    return arrays, metadata

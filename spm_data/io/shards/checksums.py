"""Checksums a shard carries, so every reader can verify what it reads (pure numpy).

Every dataset of a shard is chunked with HDF5's Fletcher-32 filter: HDF5 checks
each chunk as it is read, whatever the reader (h5py, the C library, h5dump).
Compressed frames are written as raw chunks (shards.ShardWriter.write_images), so their
checksum is computed here, exactly as HDF5's filter computes it. The file's
attributes and the layout of its datasets (dtype, shape, chunks, filters) are
covered by one CRC-32 per item, stored as the ``checksums`` attribute.
"""

from __future__ import annotations

import json
import zlib

import numpy as np

FLETCHER32 = 3  # HDF5 filter id (H5Z_FILTER_FLETCHER32)
CHECKSUMS_ATTR = "checksums"


def fletcher32(data: bytes) -> int:
    """HDF5's Fletcher-32 of ``data`` (H5_checksum_fletcher32): big-endian 16-bit
    words, an odd last byte padded with zero, sums folded modulo 65535 with
    end-around carry (so a non-zero sum is in 1..65535, never 0)."""
    if len(data) % 2:
        data = bytes(data) + b"\0"
    raw = np.frombuffer(data, ">u2")
    nonzero = bool(raw.any())  # before reducing: a 0xFFFF word is 0 mod 65535 but makes the sums non-zero
    n = len(raw)
    if n <= _EXACT_WORDS:  # the plain sums fit in int64: one pass each, reduced at the end (_fold)
        words = raw.astype(np.int64)
        s1 = int(words.sum())
        s2 = int(np.dot(words, np.arange(n, 0, -1, dtype=np.int64)))  # word i counts in n - i running sums
        return (_fold(s2, nonzero) << 16) | _fold(s1, nonzero)
    words = raw.astype(np.int64) % 65535
    weights = np.arange(n, 0, -1, dtype=np.int64) % 65535
    s1 = int(words.sum())
    s2 = int((words * weights % 65535).sum())  # reduced first: no int64 overflow on big chunks
    return (_fold(s2, nonzero) << 16) | _fold(s1, nonzero)


# Words up to which sum(word * weight) < 65535 * n**2 / 2 stays below 2**63 (about 32 MB of data)
_EXACT_WORDS = 16_000_000


def _fold(total: int, nonzero: bool) -> int:
    return (total - 1) % 65535 + 1 if nonzero else 0


def with_fletcher32(chunk: bytes) -> bytes:
    """A filtered chunk with its Fletcher-32 appended (little-endian), as HDF5 stores it."""
    return chunk + fletcher32(chunk).to_bytes(4, "little")


def stored_chunk_ok(raw: bytes) -> bool:
    """Whether a chunk as stored on disk (payload + 4-byte Fletcher-32) is intact."""
    return len(raw) >= 4 and fletcher32(raw[:-4]) == int.from_bytes(raw[-4:], "little")


def _plain(value):
    if isinstance(value, bytes):
        return value.decode("utf-8", "replace")
    if isinstance(value, np.ndarray):
        return value.tolist()
    return value.item() if hasattr(value, "item") else value


def item_crc(value) -> int:
    """CRC-32 of a JSON-able value (attribute or layout description), canonical form."""
    return zlib.crc32(json.dumps(_plain(value), sort_keys=True, default=str).encode())


def dataset_layout(ds) -> list:
    """What HDF5 needs to decode a dataset: dtype, shape, chunk shape and filter ids."""
    plist = ds.id.get_create_plist()
    filters = [plist.get_filter(i)[0] for i in range(plist.get_nfilters())]
    return [ds.dtype.str, list(ds.shape), list(ds.chunks or []), filters]


def file_checksums(f, layouts=None) -> dict:
    """{"attrs": {name: crc}, "layout": {dataset: crc}, "self": crc of those two} of an open
    h5py file (layouts: _layouts(f), when the caller has them); "self" tells a damaged
    checksums attribute from a damaged item."""
    attrs = {k: item_crc(v) for k, v in f.attrs.items() if k != CHECKSUMS_ATTR}
    layout = {name: item_crc(value) for name, value in (_layouts(f) if layouts is None else layouts).items()}
    return {"attrs": attrs, "layout": layout, "self": item_crc([attrs, layout])}


def _layouts(f) -> dict:
    """{dataset: dataset_layout}; a damaged link gives None for its object: no layout, so
    it fails its checksum."""
    return {name: dataset_layout(ds) if ds is not None else None for name, ds in f.items()}


def checksum_mismatch(f) -> str | None:
    """None when the file's attributes and dataset layouts match its stored
    checksums; else what differs, in a few words naming the item."""
    stored = f.attrs.get(CHECKSUMS_ATTR)
    try:
        stored = json.loads(stored)
        if not (isinstance(stored["attrs"], dict) and isinstance(stored["layout"], dict)):
            return "no readable checksums attribute"
        if stored["self"] != item_crc([stored["attrs"], stored["layout"]]):
            return "attribute 'checksums' fails its own checksum"
    except (TypeError, ValueError, KeyError, UnicodeDecodeError):
        return "no readable checksums attribute"
    layouts = _layouts(f)  # once: the checksums and the Fletcher-32 check below
    now = file_checksums(f, layouts)
    for kind, label in (("attrs", "attribute"), ("layout", "field")):
        for name in sorted(set(now[kind]) | set(stored[kind])):
            if now[kind].get(name) != stored[kind].get(name):
                if name not in now[kind]:
                    return f"{label} {name!r} is missing"
                if name not in stored[kind]:
                    return f"{label} {name!r} was added after writing"
                what = " (dtype, shape or filters)" if kind == "layout" else ""
                return f"{label} {name!r} fails its checksum{what}"
    if any(value is not None and FLETCHER32 not in value[3] for value in layouts.values()):
        return "a field without a Fletcher-32 checksum"
    return None

"""No frame is read twice: duplicates decided from what the shards hold, never from what a
manifest claims about them.

Two shards are one when their verified content digests (seal.py) are equal: a byte copy under
any name, whatever its manifest entry says. Two frames are one when they hold the same image
and camera under the same names: a frame's key is the SHA-256 of its stored ``rgb`` chunk's
fingerprint (encode_chunk's bytes are deterministic: a frame merged, imported or rendered again
from the same pixels has the same bytes; the fingerprint is their length, zlib's Adler-32 of the
pixels and the chunk's Fletcher-32) with its ``K``, ``R``, ``t``, class and instance name; so ``merge A M``
where M is ``merge A`` is found, while an occluded copy of a frame (other pixels), or one mesh
rendered under another class name, is a frame of its own. Frames are compared where merge put
them: a merged shard's against every other shard's (render, import and occlude write frames of
their own). A shard's keys are a function of its bytes: computed once per process for each
content digest.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

from spm_data.errors import ShardError
from spm_data.io.shards.chunks import decodable
from spm_data.io.shards.checksums import dataset_layout
from spm_data.io.shards.reader import H5_ERRORS, ShardReader, read_attrs, shard_digest
from spm_data.io.shards.seal import hash_ahead

MERGED = "merged"   # the renderer attribute of a shard spm-data merge wrote
_keys: dict[str, tuple] = {}   # content digest -> the shard's frame keys


def frame_keys(path) -> tuple[bytes, ...]:
    """Each frame's key (the module's docstring), in frame order; ShardError as every read."""
    digest = shard_digest(path)
    if digest not in _keys:
        with ShardReader(path) as reader:
            labels = reader.read(["K", "R", "t", "class_name", "instance_name"])
            images = _stored_rgb(reader)
            if images is None:   # a layout HDF5 decodes itself: the decoded pixels
                images = [frame.tobytes() for frame in reader.read(["rgb"])["rgb"]]
            _keys[digest] = tuple(
                hashlib.sha256(image + K.tobytes() + R.tobytes() + t.tobytes()
                               + f"\0{cls}\0{name}".encode("utf-8", "surrogatepass")).digest()
                for image, K, R, t, cls, name in zip(images, *labels.values()))
    return _keys[digest]


def _stored_rgb(reader: ShardReader) -> list | None:
    """Every frame's stored rgb chunk's fingerprint, or None when they are not one encoded chunk a frame."""
    try:
        ds = reader._file["rgb"]   # the reader's verified file (this package's own)
        if not decodable(dataset_layout(ds)[3], ds.chunks, ds.shape) or ds.id.get_num_chunks() != ds.shape[0]:
            return None
        out = []
        for i in range(ds.shape[0]):
            skipped, raw = ds.id.read_direct_chunk((i, 0, 0, 0))
            if skipped:
                return None
            # Its length and last 8 bytes: zlib's Adler-32 of the pixels and HDF5's Fletcher-32 of the
            # chunk, which the shard's SHA-256 vouched for; hashing every byte again cost as much as
            # the SHA-256 check itself.
            out.append(len(raw).to_bytes(8, "little") + bytes(raw[-8:]))
        return out
    except H5_ERRORS as exc:
        raise ShardError(f"{reader.path}: cannot read field 'rgb' ({type(exc).__name__}: {exc}); "
                         "the shard is corrupt") from None


def read_twice(shards, name=str) -> str | None:
    """What of ``shards`` would be read twice: two of one content, or a frame of one that is a
    frame of another (the module's docstring), each shard said as ``name(path)``; None when each
    frame is there once. A shard that cannot be read is passed over here: the read that follows
    names what is wrong."""
    shards = [Path(p) for p in shards]
    hash_ahead(shards)
    readable, by_digest = [], {}
    for path in shards:
        try:
            digest = shard_digest(path)
        except ShardError:
            continue
        if digest in by_digest:
            return (f"{name(by_digest[digest])} and {name(path)} have the same content (SHA-256 {digest[:12]}…), so "
                    f"its "
                    "frames would be read twice")
        by_digest[digest] = path
        readable.append(path)
    return _merged_frame_twice(readable, name)


def _is_merged(path) -> bool:
    try:
        return str(read_attrs(path).get("renderer", "")) == MERGED
    except ShardError:
        return False


def _merged_frame_twice(shards: list, name) -> str | None:
    """A frame of a merged shard that another shard holds too; the frames of the others first,
    so the merged copy is the one named. Only merged shards are compared: merge writes frames
    again as they were, while a render, import or occlude makes frames of its own (an occluded
    copy whose rectangle covered nothing has its source's pixels, and is still its own copy; so
    are two such frames one merge put in two of its shards, whose inputs it had checked)."""
    merged = [p for p in shards if _is_merged(p)]
    if not merged or (len(merged) == len(shards) and len({p.parent for p in shards}) == 1):
        return None   # nothing to compare: no merge, or one merge's own folder
    where: dict[bytes, tuple] = {}
    for path in [p for p in shards if p not in merged] + merged:
        try:
            keys = frame_keys(path)
        except ShardError:
            continue
        for i, key in enumerate(keys):
            first = where.setdefault(key, (path, i))
            one_merge = first[0] in merged and first[0].parent == path.parent   # one run's shards: its frames
            if first[0] != path and path in merged and not one_merge:
                return (f"frame {i} of {name(path)} is frame {first[1]} of {name(first[0])} (the same image, "
                        "camera and names), so it would be read twice")
    return None

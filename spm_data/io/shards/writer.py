"""The one shard writer: streamed, checksummed, atomic.

A shard is written to a hidden ``.NAME.partial`` file in the same folder,
sealed (the SHA-256 of its bytes into its 512-byte header, seal.py) and
``os.replace``-d to ``NAME`` once complete, so a shard that exists is whole.
Image chunks are compressed by our code on two threads (chunks.py) and stored raw
with their Fletcher-32; derived shards copy unchanged fields chunk for chunk from
their source, whose every byte its SHA-256 verified (seal.py).
"""

from __future__ import annotations

import json
import os
import re
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from spm_data.errors import ShardError, one_line
from spm_data.io.files import partial_path
from spm_data.io.shards.checksums import CHECKSUMS_ATTR, file_checksums
from spm_data.io.shards.chunks import GZIP_LEVEL, RUN, THREADS, encode_run
from spm_data.io.shards.reader import ShardReader
from spm_data.io.shards.schema import (FIELDS, IMAGE_FIELDS, OPTIONAL_FIELDS, SCHEMA_VERSION, check_arrays,
                                       expected_shape)
from spm_data.io.shards.seal import USERBLOCK, seal

LABEL_CHUNK = 4096  # frames per chunk of a label field (read whole; verified per chunk)


def _chunked(n: int, shape: tuple, per: int) -> dict:
    """create_dataset arguments for (n,) + shape in chunks of ``per`` frames; an
    empty dataset must be resizable to be chunked at all."""
    args = {"shape": (n,) + tuple(shape), "chunks": (max(1, min(n, per)),) + tuple(shape),
            "fletcher32": True, "track_times": False}
    if n == 0:
        args["maxshape"] = (None,) + tuple(shape)
    return args


def _write_label_field(f, field: str, value) -> None:
    """A small per-frame field: chunked, checksummed, uncompressed. Strings are
    fixed-length UTF-8, so their bytes sit in the checksummed chunks (variable-
    length strings live in HDF5's global heap, which has no checksum)."""
    import h5py

    if FIELDS.get(field, OPTIONAL_FIELDS.get(field))[0] == "str":
        encoded = [str(v).encode("utf-8") for v in value]
        length = max([len(e) for e in encoded] + [1])
        dtype = h5py.string_dtype("utf-8", length)
        value = np.asarray(encoded, dtype=f"S{length}").astype(dtype)
    else:
        value = np.ascontiguousarray(value)
        dtype = value.dtype
    ds = f.create_dataset(field, dtype=dtype, **_chunked(len(value), value.shape[1:], LABEL_CHUNK))
    if len(value):
        ds[...] = value


class ShardWriter:
    """Stream one shard to disk: image fields a block of frames at a time (a
    worker holds one block, whatever the shard's length), the small per-frame
    fields and attributes at the end; atomic (``.NAME.partial``, fsync,
    ``os.replace``), and every dataset checksummed.

    with ShardWriter(path, frames=n, height=h, width=w, images=("rgb", "depth", "mask")) as w:
        w.write_images(0, {"rgb": (k, h, w, 3) uint8, "depth": (k, h, w) float32, "mask": (k, h, w) uint8})
        ...
        w.finish(labels, attrs)   # labels: every other field, first axis n

    Leaving the block without ``finish`` (an exception, an interrupt) removes the
    temporary file; nothing is left behind.
    """

    def __init__(self, path, *, frames: int, height: int, width: int, images):
        self.path, self.frames, self.height, self.width = Path(path), int(frames), int(height), int(width)
        self.images = tuple(images)
        self.tmp = partial_path(self.path)
        self._written = {f: 0 for f in self.images}
        self._file = self._pool = None
        self._ahead = {}  # (field, frame index) -> (Future of a run, position in it): prepare's
        self._targets = {}  # field -> (dataset id, chunk-offset tail), for _store
        self._frame = {}  # field -> (frame shape, dtype): h5py's lookups cost more than a small frame
        self._done = False
        self.written = None  # after finish: (attrs, class names) for manifest_entry

    def __enter__(self):
        import h5py

        try:
            self._file = h5py.File(self.tmp, "w", track_order=True, userblock_size=USERBLOCK)
            for field in self.images:
                dtype = {**FIELDS, **OPTIONAL_FIELDS}[field][0]
                frame_shape = expected_shape(field, 1, self.height, self.width)[1:]
                self._frame[field] = (tuple(frame_shape), np.dtype(dtype))
                self._file.create_dataset(field, dtype=dtype, compression="gzip", compression_opts=GZIP_LEVEL,
                                          shuffle=np.dtype(dtype).itemsize > 1,
                                          **_chunked(self.frames, frame_shape, 1))
        except BaseException as exc:  # no __exit__ after a failed __enter__: clean up here
            self._abort()
            if isinstance(exc, (OSError, RuntimeError)):
                raise self._os_error(exc) from None
            raise
        self._pool = ThreadPoolExecutor(max_workers=THREADS)  # its caller waits, so normal priority
        return self

    def prepare(self, start: int, block: dict) -> None:
        """Start compressing frames ``start .. start + k`` of some image fields ({field: (k, ...)
        array}) on the writer's threads, in runs of RUN frames, while the caller makes the next
        frames; the write_images call that covers them stores these chunks (the same bytes, in
        the same order). The arrays must stay unchanged until then."""
        for field, frames in block.items():
            for run in range(0, len(frames), RUN):
                future = self._pool.submit(encode_run, frames[run: run + RUN])
                for k in range(min(RUN, len(frames) - run)):
                    self._ahead[(field, int(start) + run + k)] = (future, k)

    def check_frame(self, field: str, frame) -> np.ndarray:
        """One frame of image field ``field``, cast to its dtype (float32 normals are stored as
        float16); ShardError for a field this shard does not have or a frame of another shape."""
        if field not in self._frame:
            raise ShardError(f"shard field {field!r}: not an image field of this shard ({', '.join(self.images)})")
        shape, dtype = self._frame[field]
        if np.shape(frame) != shape:
            raise ShardError(f"shard field {field!r}: expected a frame of {shape}, got {np.shape(frame)}")
        return np.asarray(frame, dtype=dtype)

    def store_chunk(self, field: str, index: int, chunk: bytes) -> None:
        """Store one encoded chunk (encode_chunk) of frame ``index`` of ``field`` (the render
        pipeline's writer thread, pipelines/render_frames.py); HDF5 lays chunks out in the order
        they are stored, so a caller that wants write_images' bytes stores them in its order."""
        self._store([(field, index)], [chunk], {field: 1})

    def write_images(self, start: int, block: dict) -> None:
        """Frames ``start .. start + k`` of some image fields: {field: (k, ...) array}.
        Compressed on two threads (zlib releases the GIL; h5py's filters do not)
        and stored as raw chunks any HDF5 reader decodes and verifies."""
        for field, frames in block.items():
            ds = self._file[field]
            if np.shape(frames)[1:] != ds.shape[1:] or np.asarray(frames).dtype != ds.dtype:
                raise ShardError(f"shard field {field!r}: expected frames of {ds.shape[1:]} {ds.dtype}, "
                                 f"got {np.shape(frames)[1:]} {np.asarray(frames).dtype}")
        # Every (field, frame) on the pool at once, so a one-frame block keeps both threads busy;
        # chunks come back, and are stored, in field-major order.
        # Frames given to prepare are compressed already (or being compressed).
        where = [(field, start + i) for field, frames in block.items() for i in range(len(frames))]
        chunks = self._chunks(where, [frame for frames in block.values() for frame in frames])
        self._store(where, chunks, {field: len(frames) for field, frames in block.items()})

    def _store(self, where: list, chunks, counts: dict) -> None:
        """Write ``chunks`` (an iterable) at keys ``where`` [(field, frame index)], in order;
        ``counts``: frames stored per field."""
        targets = self._targets  # field -> (dataset id, chunk-offset tail): h5py's lookups cost more than a small chunk
        for field in counts:
            if field not in targets:
                ds = self._file[field]
                targets[field] = (ds.id, (0,) * (ds.ndim - 1))
        try:
            for (field, index), chunk in zip(where, chunks):
                dsid, tail = targets[field]
                dsid.write_direct_chunk((index,) + tail, chunk)
            for field, k in counts.items():
                self._written[field] += k
        except (OSError, RuntimeError) as exc:  # HDF5's object copy fails with a RuntimeError
            raise self._os_error(exc) from None

    def _chunks(self, where: list, frames: list):
        """The encoded chunks of frames (at keys where), in order: those given to prepare from
        their futures, the others compressed on the pool in a few runs of consecutive frames
        (one task per frame cost more than compressing a small frame)."""
        todo = [i for i, key in enumerate(where) if key not in self._ahead]
        runs = [todo[a: a + RUN] for a in range(0, len(todo), RUN)] if todo else []
        done = {}
        for run, future in zip(runs, [self._pool.submit(encode_run, [frames[i] for i in r]) for r in runs]):
            done[run[0]] = (run, future)
        pending = {}
        for i, key in enumerate(where):
            if key in self._ahead:
                future, position = self._ahead.pop(key)
                yield future.result()[position]
                continue
            if i not in pending:
                run, future = done.pop(i)
                pending.update(zip(run, future.result()))
            yield pending.pop(i)

    def finish(self, labels: dict, attrs: dict, copy_from=None, copied=None) -> Path:
        """Write the other fields and the attributes, then move the shard into place.
        copy_from: ``(shard path, fields)`` copied verbatim (chunks and checksums
        as stored) after verifying those chunks; for derived shards. copied: their
        stand-ins (_copy_placeholders), when the caller has them already."""
        copied = _copy_placeholders(copy_from) if copied is None else copied
        placeholders = {f: np.broadcast_to(np.zeros((), dtype), (self.frames,) + shape)
                        for f, (shape, dtype) in self._frame.items()}
        n, h, w = check_arrays({**labels, **copied, **placeholders})
        short = [f for f in self.images if self._written[f] != self.frames]
        if short or (n, h, w) != (self.frames, self.height, self.width):
            raise ShardError(f"{self.path.name}: incomplete shard ({', '.join(short) or 'shape'}); not written")
        try:
            if copy_from is not None:
                _copy_verified(copy_from, self._file)
            for field, value in labels.items():
                _write_label_field(self._file, field, value)
            for key, value in attrs.items():
                self._file.attrs[key] = value
            self._file.attrs.update({"schema_version": SCHEMA_VERSION, "frames": n, "height": h, "width": w})
            self._file.attrs[CHECKSUMS_ATTR] = json.dumps(file_checksums(self._file), sort_keys=True)
            self._file.close()
            seal(self.tmp)  # the SHA-256 of every byte after the header, into the header; fsync-ed
            os.replace(self.tmp, self.path)
        except (OSError, RuntimeError) as exc:  # HDF5's object copy fails with a RuntimeError
            raise self._os_error(exc) from None
        self._done = True
        names = {**copied, **labels}.get("class_name", [])
        self.written = ({**attrs, "schema_version": SCHEMA_VERSION, "frames": n}, names)
        return self.path

    def _os_error(self, exc: Exception) -> ShardError:
        """The one-line error for a failed write (read-only, disk full); __exit__ removes the file."""
        return ShardError(f"could not write shard {self.path}: {write_failure(exc)}")

    def _abort(self):
        if self._pool is not None:
            self._pool.shutdown(cancel_futures=True)
        if self._file is not None:
            try:
                self._file.close()
            except Exception:  # noqa: BLE001 - a failed disk; the file is removed next
                pass
        self.tmp.unlink(missing_ok=True)

    def __exit__(self, *exc):
        if self._done:
            if self._pool is not None:
                self._pool.shutdown()
        else:
            self._abort()
        return False


def write_failure(exc: Exception) -> str:
    """Why a write failed, in a few words: the system's text for the errno HDF5 reports
    inside its message ("... errno = 28 ..." is "No space left on device"), else the
    message on one line."""
    found = re.search(r"errno = (\d+)", str(exc))
    code = int(found.group(1)) if found else getattr(exc, "errno", None)
    if code:
        return os.strerror(code)
    return one_line(getattr(exc, "strerror", None) or exc)


def _copy_placeholders(copy_from) -> dict:
    """Shape-and-dtype stand-ins for fields a derived shard copies (for check_arrays)."""
    if copy_from is None:
        return {}
    source, names = copy_from
    if not isinstance(source, ShardReader):
        with ShardReader(source) as reader:
            return _copy_placeholders((reader, names))
    copied = source.read([f for f in names if f not in IMAGE_FIELDS])  # small; verified
    for f, (shape, dtype) in source.layout().items():
        if f in names and f in IMAGE_FIELDS:
            copied[f] = np.broadcast_to(np.zeros((), dtype), shape)
    return copied


def _copy_verified(copy_from, dst) -> None:
    """Copy fields verbatim (HDF5's object copy: chunks and their checksums as stored) from
    a source whose every byte matched its SHA-256 when opened (ShardReader): a derived shard
    never carries data nobody verified."""
    source, names = copy_from
    if not isinstance(source, ShardReader):
        with ShardReader(source) as reader:
            return _copy_verified((reader, names), dst)
    source.copy_fields(names, dst)


def write_shard(path, arrays: dict, attrs: dict, copy_from=None) -> Path:
    """Write one whole shard atomically (ShardWriter with a single block).

    arrays: every field of FIELDS (and any of OPTIONAL_FIELDS), first axis N
    frames. attrs: file attributes (str, int, float); ``schema_version``,
    ``frames``, ``height``, ``width`` and ``checksums`` are set here. Image
    fields are chunked one frame per chunk, gzip level 1 after byte shuffling
    (deterministic; LZF is not: liblzf leaves its hash table uninitialised).
    copy_from: ``(shard path, fields)`` copied verbatim from that shard (HDF5
    object copy, no codec work) after checking their checksums.
    """
    path = Path(path)
    copied = _copy_placeholders(copy_from)
    n, h, w = check_arrays({**arrays, **copied})
    images = [f for f in IMAGE_FIELDS if f in arrays]
    with ShardWriter(path, frames=n, height=h, width=w, images=images) as writer:
        writer.write_images(0, {f: np.ascontiguousarray(arrays[f]) for f in images})
        return writer.finish({f: v for f, v in arrays.items() if f not in images}, attrs, copy_from, copied)

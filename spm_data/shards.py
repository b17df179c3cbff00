"""HDF5 shards and the per-folder manifest: one writer, one reader (docs/shard-format.md).

A shard is written to a hidden ``.NAME.partial`` file in the same folder and
``os.replace``-d to ``NAME`` once complete, so a shard that exists is whole.
``manifest.json`` is written last, the same way.
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import json
import os
import zlib
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from spm_data.checksums import (CHECKSUMS_ATTR, FLETCHER32, checksum_mismatch, dataset_layout,
                                file_checksums, stored_chunk_ok, with_fletcher32)
from spm_data.errors import ShardError

SCHEMA_VERSION = 2  # 2: every dataset checksummed (Fletcher-32), strings fixed-length
SHARD_SUFFIX = ".h5"
MANIFEST = "manifest.json"
PARTIAL_PREFIX = "."
PARTIAL_SUFFIX = ".partial"

# name -> (dtype, per-frame shape; "H", "W" and "R" are filled in per shard)
FIELDS: dict[str, tuple[str, tuple]] = {
    "rgb": ("uint8", ("H", "W", 3)),
    "depth": ("float32", ("H", "W")),
    "mask": ("uint8", ("H", "W")),
    "K": ("float64", (3, 3)),
    "R": ("float64", (3, 3)),
    "t": ("float64", (3,)),
    "pose": ("float64", (6,)),
    "azimuth": ("float64", ()),
    "elevation": ("float64", ()),
    "roll": ("float64", ()),
    "distance": ("float64", ()),
    "look_at": ("float64", (3,)),
    "path_index": ("int64", ()),
    "instance_id": ("int64", ()),
    "instance_name": ("str", ()),
    "class_name": ("str", ()),
    "source": ("str", ()),
    "label_measured": ("bool", (6,)),
    "occlusion_fraction": ("float32", ()),
    "occlusion_rects": ("int32", ("R", 4)),
}
OPTIONAL_FIELDS: dict[str, tuple[str, tuple]] = {
    "visible_mask": ("uint8", ("H", "W")),   # object minus occluders (spm-data occlude)
    "source_shard": ("str", ()),             # the shard a derived frame came from
    "source_frame": ("int64", ()),           # its frame index there
}
IMAGE_FIELDS = ("rgb", "depth", "mask", "visible_mask")
REQUIRED_ATTRS = ("schema_version", "frames", "renderer", "seed")
SOURCES = ("synthetic", "coil100", "cvl", "folder", "bop")


def _expected_shape(field: str, n: int, h: int, w: int, r: int) -> tuple:
    spec = {**FIELDS, **OPTIONAL_FIELDS}[field][1]
    return (n,) + tuple({"H": h, "W": w, "R": r}.get(d, d) for d in spec)


def check_arrays(arrays: dict) -> tuple[int, int, int]:
    """Validate a shard's arrays against the schema; returns (N, H, W)."""
    missing = [f for f in FIELDS if f not in arrays]
    if missing:
        raise ShardError(f"shard arrays are missing {', '.join(missing)}")
    unknown = [f for f in arrays if f not in FIELDS and f not in OPTIONAL_FIELDS]
    if unknown:
        raise ShardError(f"shard arrays have unknown fields {', '.join(unknown)}")
    n, h, w = np.asarray(arrays["rgb"]).shape[:3]
    r = np.asarray(arrays["occlusion_rects"]).shape[1] if np.ndim(arrays["occlusion_rects"]) == 3 else 1
    for field, value in arrays.items():
        dtype = {**FIELDS, **OPTIONAL_FIELDS}[field][0]
        shape = _expected_shape(field, n, h, w, r)
        got = np.shape(value)
        if got != shape:
            raise ShardError(f"shard field {field!r}: expected shape {shape}, got {got}")
        if dtype != "str" and np.asarray(value).dtype != np.dtype(dtype):
            raise ShardError(f"shard field {field!r}: expected dtype {dtype}, got {np.asarray(value).dtype}")
    return n, h, w


GZIP_LEVEL = 1
LABEL_CHUNK = 4096  # frames per chunk of a label field (read whole; verified per chunk)


def encode_chunk(frame: np.ndarray) -> bytes:
    """One frame as HDF5's filters store it: byte shuffle (multi-byte dtypes
    only), deflate level 1 (zlib format), then the Fletcher-32 checksum
    (checksums.py). Deterministic."""
    a = np.ascontiguousarray(frame)
    if a.dtype.itemsize > 1:
        a = a.view(np.uint8).reshape(-1, a.dtype.itemsize).T  # HDF5 shuffle: byte planes
    return with_fletcher32(zlib.compress(np.ascontiguousarray(a), GZIP_LEVEL))  # zlib reads the buffer: no copy


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


def partial_path(path: Path) -> Path:
    return path.with_name(PARTIAL_PREFIX + path.name + PARTIAL_SUFFIX)


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
        self._done = False

    def __enter__(self):
        import h5py

        try:
            self._file = h5py.File(self.tmp, "w", track_order=True)
            for field in self.images:
                dtype = {**FIELDS, **OPTIONAL_FIELDS}[field][0]
                frame_shape = _expected_shape(field, 1, self.height, self.width, 1)[1:]
                self._file.create_dataset(field, dtype=dtype, compression="gzip", compression_opts=GZIP_LEVEL,
                                          shuffle=np.dtype(dtype).itemsize > 1,
                                          **_chunked(self.frames, frame_shape, 1))
        except BaseException as exc:  # no __exit__ after a failed __enter__: clean up here
            self._abort()
            if isinstance(exc, OSError):
                raise self._os_error(exc) from None
            raise
        self._pool = ThreadPoolExecutor(max_workers=2)
        return self

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
        where = [(field, start + i) for field, frames in block.items() for i in range(len(frames))]
        chunks = self._pool.map(encode_chunk, (frame for frames in block.values() for frame in frames))
        try:
            for (field, index), chunk in zip(where, chunks):
                ds = self._file[field]
                ds.id.write_direct_chunk((index,) + (0,) * (ds.ndim - 1), chunk)
            for field, frames in block.items():
                self._written[field] += len(frames)
        except OSError as exc:
            raise self._os_error(exc) from None

    def finish(self, labels: dict, attrs: dict, copy_from=None, copied=None) -> Path:
        """Write the other fields and the attributes, then move the shard into place.
        copy_from: ``(shard path, fields)`` copied verbatim (chunks and checksums
        as stored) after verifying those chunks; for derived shards. copied: their
        stand-ins (_copy_placeholders), when the caller has them already."""
        copied = _copy_placeholders(copy_from) if copied is None else copied
        placeholders = {f: np.broadcast_to(np.zeros((), self._file[f].dtype), self._file[f].shape)
                        for f in self.images}
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
            with open(self.tmp, "rb") as fh:
                os.fsync(fh.fileno())
            os.replace(self.tmp, self.path)
        except OSError as exc:
            raise self._os_error(exc) from None
        self._done = True
        return self.path

    def _os_error(self, exc: OSError) -> ShardError:
        """The one-line error for a failed write (read-only, disk full); __exit__ removes the file."""
        return ShardError(f"could not write shard {self.path}: {exc.strerror or exc}")

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
            self._pool.shutdown()
        else:
            self._abort()
        return False


def _copy_placeholders(copy_from) -> dict:
    """Shape-and-dtype stand-ins for fields a derived shard copies (for check_arrays)."""
    if copy_from is None:
        return {}
    source, names = copy_from
    copied = read_shard(source, [f for f in names if f not in IMAGE_FIELDS])  # small; verified
    with _open(source) as src:
        for f in names:
            if f in IMAGE_FIELDS:
                copied[f] = np.broadcast_to(np.zeros((), src[f].dtype), src[f].shape)
    return copied


def _copy_verified(copy_from, dst) -> None:
    """Copy fields verbatim, each chunk's checksum checked first: a derived shard
    never carries data nobody verified."""
    source, names = copy_from
    with _open(source) as src:
        for field in names:
            verify_stored_chunks(source, src, field)
            src.copy(src[field], dst, name=field)


def verify_stored_chunks(path, f, field: str) -> None:
    """Check every stored chunk of ``f[field]`` against its Fletcher-32 without
    decompressing it; a ShardError naming the shard and field on a mismatch."""
    try:
        ds = f[field]
        if FLETCHER32 not in dataset_layout(ds)[3]:
            raise ShardError(f"{path}: field {field!r} has no checksum; it cannot be verified")
        for i in range(ds.id.get_num_chunks()):
            info = ds.id.get_chunk_info(i)
            if not stored_chunk_ok(ds.id.read_direct_chunk(info.chunk_offset)[1]):
                raise ShardError(f"{path}: field {field!r} fails its checksum (frames from "
                                 f"{info.chunk_offset[0]}); the shard is corrupt")
    except ShardError:
        raise
    except (*H5_ERRORS, UnicodeDecodeError) as exc:
        raise ShardError(f"{path}: field {field!r} is corrupt ({type(exc).__name__}: {exc})") from None


def verify_shard(path) -> dict:
    """Check a whole shard (attributes, layout, every chunk) without decoding it;
    returns its attributes (read_attrs)."""
    with _open(path) as f:
        attrs = _verified_attrs(path, f)
        for field in list(f.keys()):
            verify_stored_chunks(path, f, field)
    return attrs


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


def _open(path):
    import h5py

    path = Path(path)
    if not path.is_file():
        raise ShardError(f"shard not found: {path}")
    try:
        return h5py.File(path, "r")
    except OSError as exc:
        raise ShardError(f"{path}: not a readable HDF5 shard ({exc})") from None


# What h5py raises for a damaged file besides OSError (a bad object header is a KeyError).
H5_ERRORS = (OSError, KeyError, ValueError, RuntimeError, TypeError, IndexError)


def read_attrs(path) -> dict:
    """A shard's file attributes as plain Python values, verified against its
    checksums (with the layout of its fields); checks the schema version."""
    with _open(path) as f:
        return _verified_attrs(path, f)


def _verified_attrs(path, f) -> dict:
    """read_attrs on an open file."""
    try:
        attrs = {k: (v.item() if hasattr(v, "item") else v) for k, v in f.attrs.items()}
        version = attrs.get("schema_version")
        mismatch = checksum_mismatch(f) if version is not None and int(version) >= 2 else None
    except H5_ERRORS as exc:
        if isinstance(exc, ShardError):
            raise
        raise ShardError(f"{path}: corrupt shard attributes ({type(exc).__name__}: {exc})") from None
    if version is None:
        raise ShardError(f"{path}: not an spm shard (no schema_version attribute)")
    if int(version) > SCHEMA_VERSION:
        raise ShardError(f"{path}: schema version {version} is newer than this spm "
                         f"({SCHEMA_VERSION}); upgrade spm to read it")
    if int(version) < SCHEMA_VERSION:
        raise ShardError(f"{path}: schema version {version} has no checksums, so it cannot be verified; "
                         "make it again with this spm (render, import or occlude into a new --out)")
    if mismatch:
        raise ShardError(f"{path}: {mismatch}; the shard is corrupt")
    attrs.pop(CHECKSUMS_ATTR, None)
    return attrs


def read_shard(path, fields=None, frames=slice(None)) -> dict:
    """Read ``fields`` (default: all present) of a shard, for ``frames`` (a slice
    or sorted index array). String fields come back as (n,) object arrays of str.
    Verified: the attributes and layout first (read_attrs), then HDF5 checks the
    Fletcher-32 of every chunk it reads; a mismatch is a ShardError naming the field."""
    with ShardReader(path) as reader:
        return reader.read(fields, frames)


def h5_is_string(ds) -> bool:
    import h5py

    return h5py.check_string_dtype(ds.dtype) is not None


def list_shards(folder) -> list[Path]:
    """The complete shards directly in ``folder`` or, for a file, that file."""
    folder = Path(folder)
    if folder.is_file():
        return [folder]
    if not folder.is_dir():
        raise ShardError(f"no such folder or shard: {folder}")
    return sorted(p for p in folder.iterdir()
                  if p.suffix == SHARD_SUFFIX and not p.name.startswith(PARTIAL_PREFIX))


def file_sha256(path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def manifest_entry(path) -> dict:
    """One manifest row for a complete shard: counts per class and a checksum."""
    path = Path(path)
    attrs = read_attrs(path)
    names = read_shard(path, ["class_name"])["class_name"]
    classes, counts = np.unique(names.astype(str), return_counts=True) if len(names) else ([], [])
    return {"file": path.name, "frames": int(attrs["frames"]), "bytes": path.stat().st_size,
            "sha256": file_sha256(path), "classes": {str(c): int(k) for c, k in zip(classes, counts)},
            "renderer": str(attrs.get("renderer", "")), "schema_version": int(attrs["schema_version"])}


@contextlib.contextmanager
def atomic_file(path, tmp=None):
    """Yield a temporary path beside ``path`` (default ``.NAME.partial``); when the
    block completes it becomes ``path`` (os.replace), when it raises it is removed,
    so ``path`` is either the old file or the whole new one."""
    path = Path(path)
    tmp = Path(tmp) if tmp is not None else partial_path(path)
    try:
        yield tmp
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def write_npz_atomic(path, tmp=None, **arrays) -> Path:
    """``np.savez`` to ``path`` atomically (atomic_file). Built in memory, then written in
    one go: np.savez leaves its zip file open when a write fails (disk full), and Python
    then prints that zip file's error on exit, after our one-line message."""
    npz = io.BytesIO()
    np.savez(npz, **arrays)
    with atomic_file(path, tmp) as partial, open(partial, "wb") as fh:
        fh.write(npz.getbuffer())
    return Path(path)


def write_json_atomic(path, payload) -> None:
    with atomic_file(path) as tmp, open(tmp, "w") as fh:
        json.dump(payload, fh, indent=2, sort_keys=True)
        fh.write("\n")
        fh.flush()
        os.fsync(fh.fileno())


def write_manifest(folder, known: dict | None = None, extra: dict | None = None, names=None) -> dict:
    """(Re)write ``folder/manifest.json``: the shards the old manifest listed and,
    of ``names`` (this run's shards), those complete on disk. Any other ``.h5``
    in the folder is not adopted (``names=None``: every complete shard on disk).

    known: entries already computed this run, by file name (saves re-hashing);
    entries of the old manifest are reused when size still matches.
    extra: more top-level keys (e.g. merge's ``sources``); an old manifest's are kept.
    """
    folder = Path(folder)
    old, old_extra = {}, {}
    if (folder / MANIFEST).exists():
        try:
            previous = read_manifest(folder)
            old = {e["file"]: e for e in previous["shards"] if isinstance(e, dict) and "file" in e}
            old_extra = {k: v for k, v in previous.items() if k not in ("schema_version", "shards", "frames", "classes")}
        except (ShardError, TypeError):
            old = {}
    known = dict(known or {})
    wanted = None if names is None else set(old) | set(names)
    entries = []
    for path in list_shards(folder):
        if wanted is not None and path.name not in wanted:
            continue
        entry = known.get(path.name) or old.get(path.name)
        if entry is None or entry.get("bytes") != path.stat().st_size:
            entry = manifest_entry(path)
        entries.append(entry)
    classes: dict[str, int] = {}
    for e in entries:
        for c, k in e["classes"].items():
            classes[c] = classes.get(c, 0) + k
    payload = {**old_extra, **(extra or {}), "schema_version": SCHEMA_VERSION, "shards": entries,
               "frames": sum(e["frames"] for e in entries), "classes": dict(sorted(classes.items()))}
    write_json_atomic(folder / MANIFEST, payload)
    return payload


def read_manifest(folder) -> dict:
    path = Path(folder) / MANIFEST
    try:
        with open(path) as fh:
            payload = json.load(fh)
    except FileNotFoundError:
        raise ShardError(f"{folder}: no {MANIFEST}") from None
    except IsADirectoryError:
        raise ShardError(f"{path} is a folder, not a manifest; move it away and run the command again") from None
    except (OSError, ValueError) as exc:
        raise ShardError(f"{path}: unreadable manifest ({getattr(exc, 'strerror', None) or exc})") from None
    if not isinstance(payload, dict) or not isinstance(payload.get("shards"), list):
        raise ShardError(f"{path}: manifest has no 'shards' list")
    return payload


def remove_partials(folder) -> list[Path]:
    """Delete ``.*.partial`` leftovers of killed runs in ``folder``; returns them."""
    folder = Path(folder)
    stale = [p for p in folder.glob(PARTIAL_PREFIX + "*" + PARTIAL_SUFFIX)] if folder.is_dir() else []
    for p in stale:
        p.unlink(missing_ok=True)
    return stale


class ShardReader:
    """One shard held open for many small reads (a training loop reading a frame
    at a time; spm_data.loaders). Opening verifies the attributes and layout once
    (read_attrs); each ``read`` is then checked by HDF5's Fletcher-32 on every
    chunk it touches, with read_shard's errors (read_shard is this, opened once).
    An h5py handle is not safe across fork: open one per process.

    with ShardReader(path) as r:
        r.attrs["frames"], r.fields()
        r.read(["rgb", "K"], frames=5)   # {"rgb": (H, W, 3) uint8, "K": (3, 3) float64}
    """

    def __init__(self, path):
        self.path = Path(path)
        self.pid = os.getpid()
        self._file = _open(self.path)
        try:
            self.attrs = _verified_attrs(self.path, self._file)
        except BaseException:
            self._file.close()
            raise

    def fields(self) -> list[str]:
        """The names of the fields this shard has, in file order."""
        try:
            return list(self._file.keys())
        except H5_ERRORS as exc:
            raise ShardError(f"{self.path}: corrupt shard index ({type(exc).__name__}: {exc})") from None

    def read(self, fields=None, frames=slice(None)) -> dict:
        """``fields`` (default: all) for ``frames``: a slice or sorted index array
        (first axis kept; strings as object arrays of str) or one int (that frame:
        an array without the frame axis, a numpy scalar, or a str)."""
        return {name: self._read_field(name, frames) for name in (self.fields() if fields is None else fields)}

    def _read_field(self, name: str, frames):
        try:
            if name not in self._file:
                raise ShardError(f"{self.path}: shard has no field {name!r}")
            ds = self._file[name]
            if h5_is_string(ds):
                value = ds.asstr()[frames]
                return value if isinstance(value, str) else np.asarray(value, dtype=object)
            return ds[frames]
        except ShardError:
            raise
        except (*H5_ERRORS, UnicodeDecodeError) as exc:
            raise ShardError(f"{self.path}: field {name!r} fails its checksum or cannot be decoded; "
                             "the shard is corrupt") from None

    def close(self) -> None:
        self._file.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False

"""The one shard reader: every read verified.

Opening a shard checks every byte of it against the SHA-256 in its header
(seal.py) before HDF5 reads anything; ``read_attrs`` then checks the attributes
and each field's layout against their CRC-32s, and HDF5 the Fletcher-32 of every
chunk a read touches. A shard that fails is a one-line ShardError naming it and,
where the finer checks find it, the field or attribute that changed.
"""

from __future__ import annotations

import errno
import os
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from spm_data.errors import ShardError
from spm_data.io.shards.checksums import CHECKSUMS_ATTR, FLETCHER32, checksum_mismatch, dataset_layout, stored_chunk_ok
from spm_data.io.shards.chunks import SHUFFLE, THREADS, decodable, decode_run, runs
from spm_data.io.shards.schema import SCHEMA_VERSION
from spm_data.io.shards.seal import SealError, forget, verified_digest


def open_h5(path):
    """An h5py file of a shard whose every byte matched its SHA-256 (seal.py)."""
    path = Path(path)
    shard_digest(path)
    return _h5_file(path)


_checked: dict[str, dict] = {}  # content digest -> its attributes, checked (_checked_attrs)


def shard_digest(path) -> str:
    """The verified SHA-256 of a shard's content (seal.py): every byte is checked, once
    per process while the file is unchanged. A ShardError naming the shard otherwise."""
    path = Path(path)
    if not path.is_file():
        raise ShardError(f"shard not found: {path}" + (" (a folder)" if path.is_dir() else ""))
    try:
        return verified_digest(path)
    except SealError as exc:
        raise _unverified(path, exc) from None
    except OSError as exc:
        raise _open_error(path, exc, f"cannot read the shard ({exc.strerror or exc})") from None


def _h5_file(path):
    import h5py

    try:
        return h5py.File(path, "r")
    except OSError as exc:
        raise _open_error(path, exc, f"not a readable HDF5 shard ({exc})") from None


def _open_error(path, exc: OSError, otherwise: str) -> ShardError:
    """Running out of file descriptors said as such; else ``otherwise``."""
    if exc.errno in (errno.EMFILE, errno.ENFILE) or "Too many open files" in str(exc):
        return ShardError(f"{path}: cannot open, too many open files in this process (the limit is "
                          f"ulimit -n, {_open_file_limit()}); close readers or raise the limit")
    return ShardError(f"{path}: {otherwise}")


def _open_file_limit() -> str:
    import resource

    return str(resource.getrlimit(resource.RLIMIT_NOFILE)[0])


def _unverified(path, exc: SealError) -> ShardError:
    """The error for a shard that fails its whole-file check: the changed field or attribute
    when the finer checks find it, else the whole-file finding."""
    if exc.mismatch:
        try:
            with _h5_file(path) as f:
                _verified_attrs(path, f)
                for field in list(f.keys()):
                    verify_stored_chunks(path, f, field)
        except ShardError as found:
            return found
        except Exception:  # noqa: BLE001 - damaged metadata makes h5py raise anything; the file is corrupt anyway
            pass
        return ShardError(f"{path}: {exc}; the shard is corrupt")
    return ShardError(f"{path}: {exc}")


# What h5py raises for a damaged file besides OSError (a bad object header is a KeyError).
H5_ERRORS = (OSError, KeyError, ValueError, RuntimeError, TypeError, IndexError)


def read_attrs(path) -> dict:
    """A shard's file attributes as plain Python values, verified against its
    checksums (with the layout of its fields); checks the schema version."""
    with ShardReader(path) as reader:
        return reader.attrs


def forget_checks() -> None:
    """Forget every check this process made (seal.forget and the attribute checks): the next
    open of any shard hashes it and checks its attributes again (a benchmark's fresh start)."""
    forget()
    _checked.clear()


def _checked_attrs(path, f, digest: str) -> dict:
    """_verified_attrs of an open file whose content hashes to ``digest`` (verified): the
    check is a function of those bytes, so it runs once per process for each digest."""
    if digest not in _checked:
        _checked[digest] = _verified_attrs(path, f)
    return dict(_checked[digest])


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
        raise ShardError(f"{path}: schema version {version} is older than this spm ({SCHEMA_VERSION}) and cannot "
                         "be verified; make it again with this spm (render, import or occlude into a new --out)")
    if mismatch:
        raise ShardError(f"{path}: {mismatch}; the shard is corrupt")
    attrs.pop(CHECKSUMS_ATTR, None)
    return attrs


def read_shard(path, fields=None, frames=slice(None)) -> dict:
    """Read ``fields`` (default: all present) of a shard, for ``frames`` (a slice
    or sorted index array). String fields come back as (n,) object arrays of str.
    Verified: every byte of the file (open_h5), the attributes and layout
    (read_attrs), then HDF5 checks the Fletcher-32 of every chunk it reads; a
    mismatch is a ShardError naming the shard (and the field, where found)."""
    with ShardReader(path) as reader:
        return reader.read(fields, frames)


def shard_layout(path) -> dict:
    """A shard's fields: name -> (shape, dtype name), its attributes verified first."""
    with ShardReader(path) as reader:
        return reader.layout()


def h5_is_string(ds) -> bool:
    import h5py

    return h5py.check_string_dtype(ds.dtype) is not None


class ShardReader:
    """One shard held open for many small reads (a training loop reading a frame
    at a time; spm_data.io.loaders). Opening verifies every byte of the file and
    the attributes and layout once (open_h5, read_attrs); each ``read`` is then
    checked by HDF5's Fletcher-32 on every chunk it touches, with read_shard's
    errors (read_shard is this, opened once).
    An h5py handle is not safe across fork: open one per process.

    with ShardReader(path) as r:
        r.attrs["frames"], r.fields()
        r.read(["rgb", "K"], frames=5)   # {"rgb": (H, W, 3) uint8, "K": (3, 3) float64}
    """

    def __init__(self, path):
        self.path = Path(path)
        self.pid = os.getpid()
        self._pool = None  # threads decoding ahead (read_runs)
        self._layout = None  # layout(), once looked up
        self.digest = shard_digest(self.path)  # every byte checked (seal.py), then opened
        self._file = _h5_file(self.path)
        try:
            self.attrs = _checked_attrs(self.path, self._file, self.digest)
        except BaseException:
            self._file.close()
            raise

    def fields(self) -> list[str]:
        """The names of the fields this shard has, in file order."""
        try:
            return list(self._file.keys())
        except H5_ERRORS as exc:
            raise ShardError(f"{self.path}: corrupt shard index ({type(exc).__name__}: {exc})") from None

    def layout(self) -> dict:
        """Every field: name -> (shape, dtype name; "str" for strings), in file order (looked up
        once per open: the file is read-only and h5py's lookups cost more than a small read)."""
        if self._layout is None:
            try:
                self._layout = {name: (ds.shape, "str" if h5_is_string(ds) else str(ds.dtype))
                                for name, ds in self._file.items()}
            except H5_ERRORS as exc:
                raise ShardError(f"{self.path}: corrupt shard index ({type(exc).__name__}: {exc})") from None
        return dict(self._layout)

    def read(self, fields=None, frames=slice(None)) -> dict:
        """``fields`` (default: all) for ``frames``: a slice or sorted index array
        (first axis kept; strings as object arrays of str) or one int (that frame:
        an array without the frame axis, a numpy scalar, or a str)."""
        return {name: self._read_field(name, frames) for name in (self.fields() if fields is None else fields)}

    def _read_field(self, name: str, frames):
        try:
            if name == "depth" and name not in self._file:   # optional; absent reads as 0 (schema.py)
                return self._zero_depth(frames)
            if name not in self._file:
                raise ShardError(f"{self.path}: shard has no field {name!r}")
            ds = self._file[name]
            if h5_is_string(ds):
                value = ds.asstr()[frames]
                return value if isinstance(value, str) else np.asarray(value, dtype=object)
            decoded = self._decoded(name, ds, frames)
            return ds[frames] if decoded is None else decoded
        except ShardError:
            raise
        except (OSError, UnicodeDecodeError):  # a chunk failing its Fletcher-32, or not decoding
            raise ShardError(f"{self.path}: field {name!r} fails its checksum or cannot be decoded; "
                             "the shard is corrupt") from None
        except H5_ERRORS as exc:  # the bytes were verified: a request h5py cannot serve, not corruption
            raise ShardError(f"{self.path}: cannot read field {name!r} for frames {_describe(frames)} "
                             f"({type(exc).__name__}: {exc})") from None

    def _zero_depth(self, frames) -> np.ndarray:
        """The depth of a shard that has none (an import without depth): 0, no surface measured."""
        shape = np.shape(np.arange(int(self.attrs["frames"]))[frames]) + (self.attrs["height"], self.attrs["width"])
        return np.zeros(tuple(int(d) for d in shape), np.float32)

    def read_runs(self, name: str) -> list:
        """An image field's frames run by run (chunks.RUN frames): [(frame range, get)], where
        ``get()`` returns that run's (k, ...) array. The runs are decoded on the reader's threads
        from now on, in order, so a caller working on one run finds the next decoded."""
        if name not in self.fields():
            raise ShardError(f"{self.path}: shard has no field {name!r}")
        n = self._file[name].shape[0]
        source = self._chunk_source(self._file[name], range(n))
        if source is None:  # HDF5 decodes it, run by run when asked
            return [(run, lambda run=run: self._read_field(name, slice(run.start, run.stop))) for run in runs(n)]
        raws, out, shuffled = source
        if self._pool is None:
            self._pool = ThreadPoolExecutor(THREADS)
        got = []
        for run in runs(n):
            future = self._pool.submit(decode_run, raws[run.start:run.stop], out, run.start, shuffled)
            got.append((run, lambda run=run, future=future: self._decoded_run(name, out, run, future.result())))
        return got

    def _decoded_run(self, name: str, out: np.ndarray, run: range, failed):
        if failed is not None:
            raise ShardError(f"{self.path}: field {name!r} fails its checksum or cannot be decoded (frame "
                             f"{failed}); the shard is corrupt")
        return out[run.start:run.stop]

    def _decoded(self, name: str, ds, frames):
        """``ds[frames]`` for a slice of an image field, decoded by chunks.py on THREADS threads
        from the stored chunks; None for what HDF5 decodes (other layouts and filters, index
        arrays, unwritten chunks)."""
        if not isinstance(frames, slice) or ds.ndim < 2:
            return None
        index = range(ds.shape[0])[frames]
        source = self._chunk_source(ds, index)
        if source is None:
            return None
        raws, out, shuffled = source
        parts = runs(len(raws))
        if len(parts) > 1:
            with ThreadPoolExecutor(THREADS) as pool:
                failed = list(pool.map(lambda r: decode_run(raws[r.start:r.stop], out, r.start, shuffled), parts))
        else:
            failed = [decode_run(raws, out, 0, shuffled)]
        return self._decoded_run(name, out, range(len(out)),
                                 min((index[k] for k in failed if k is not None), default=None))

    @staticmethod
    def _chunk_source(ds, index: range):
        """(stored chunks of frames ``index``, the array to decode them into, shuffled?) for a
        dataset chunks.py decodes; None otherwise. The chunks' bytes are those the SHA-256
        verified when the shard was opened (their Fletcher-32 is for readers without spm)."""
        filters = dataset_layout(ds)[3]
        if ds.ndim < 2 or not decodable(filters, ds.chunks, ds.shape) or ds.id.get_num_chunks() != ds.shape[0]:
            return None
        tail = (0,) * (ds.ndim - 1)
        raws = []
        for i in index:
            skipped, raw = ds.id.read_direct_chunk((i, *tail))
            if skipped:  # a filter was not applied to this chunk: HDF5 knows how to read it
                return None
            raws.append(raw)
        return raws, np.empty((len(index), *ds.shape[1:]), ds.dtype), SHUFFLE in filters

    def copy_fields(self, names, dst) -> None:
        """Copy fields verbatim into the open h5py file ``dst`` (HDF5's object copy: chunks and
        their Fletcher-32 as stored, no codec work); their bytes matched the SHA-256 at open.
        A failed write is HDF5's RuntimeError or OSError (the writer says which)."""
        for field in names:
            if field not in self._file:
                raise ShardError(f"{self.path}: shard has no field {field!r}")
            self._file.copy(self._file[field], dst, name=field)

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(cancel_futures=True)
        self._file.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False


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
    """Check a whole shard (every byte against its SHA-256, then its attributes and
    layout) without decoding it; returns its attributes (read_attrs)."""
    return read_attrs(path)


def _describe(frames) -> str:
    if isinstance(frames, slice):
        return f"{frames.start or 0}:{'' if frames.stop is None else frames.stop}"
    values = np.ravel(frames)
    return str(values.tolist()) if values.size <= 6 else f"[{values[0]}, {values[1]}, ... {values[-1]}] ({values.size})"

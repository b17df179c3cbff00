"""Shard folders as training-loop datasets: a frame by index, read and verified.

``ShardDataset`` is a map-style dataset (``len`` and ``[i]``), the protocol
``torch.utils.data.DataLoader`` takes, without importing torch: spm does not
depend on it. Frames are read through ``spm_data.io.shards.ShardReader``, so no frame
is returned from a shard before every byte of it matched its SHA-256 (seal.py), in
this process; then HDF5's Fletcher-32 checks every chunk read.

When shards are verified (``on_corrupt``): with ``"refuse"`` (the default) construction
takes the frame counts from ``manifest.json`` and hashes only the first shard (for the
field list) and any shard the manifest gives no count for; every other shard is hashed
on its first read in each process (a forked worker reuses what its parent verified), so
the first item comes after one shard's hash, not the folder's. A corrupt shard is then a
ShardError naming it, at construction or on the first read of one of its frames (the
other shards stay readable). With ``"skip"`` construction hashes every shard, as it
always did before (two threads; 4 s for a 975 MB folder on a loaded 2-core machine,
docs/reliability.md), leaves out the corrupt ones with one warning each, and ``len``
counts only the frames of the shards kept; a shard that fails later (changed on disk
since) is a ShardError.

Process safety: an h5py handle must not cross a fork (pytorch/pytorch#11929).
The dataset keeps no handle from ``__init__``; each process opens a shard on its
first read of it and keeps it, keyed by the process id, so a forked worker
(DataLoader's default on Linux) reopens instead of using its parent's handle,
and pickling (spawn workers) carries no handle at all. A process keeps at most
``max_open`` shards open (the least recently read is closed first), so a folder
of thousands of shards never runs into the open-file limit.
"""

from __future__ import annotations

import multiprocessing
import operator
import os
import warnings
from collections import OrderedDict

import numpy as np

from spm_data.errors import ShardError, SpmWarning, one_line
from spm_data.io.folders import open_folder
from spm_data.io.shards import (FIELDS, H5_ERRORS, MANIFEST, OPTIONAL_FIELDS, ShardReader, h5_is_string, hash_ahead,
                                reuse_verification, verification)

MAX_OPEN = 64  # shards a process keeps open: well under the usual open-file limit (1024)
ON_CORRUPT = ("refuse", "skip")


class ShardDataset:
    """Every frame of a shard folder, in manifest order, as a dict of numpy values.

    ds = ShardDataset("out/", fields=("rgb", "K", "pose", "class_name"))
    len(ds)          # frames over all shards the manifest lists
    ds[i]            # {"rgb": (H, W, 3) uint8, "K": (3, 3) float64,
                     #  "pose": (6,) float64, "class_name": str}
    ds[-1]           # the last frame, as for a list

    An item holds, per field, ``read_shard(shard, [field])[field][j]`` for the
    frame's shard and index j there: images (H, W, 3) / (H, W) arrays, per-frame
    vectors and matrices as arrays (dtypes of ``spm_data.io.shards.FIELDS``), scalar
    fields as numpy scalars, string fields as Python ``str``.

    folder: a shard folder (read by its manifest, ``spm_data.io.folders.open_folder``:
    a folder a live run is writing is refused) or one shard file.
    fields: names from FIELDS / OPTIONAL_FIELDS; default every field the shards
    verified at construction have (with "refuse": the first shard's). A shard without
    one of them is a ShardError naming it. transform: ``item -> item``, applied after
    reading (in the worker).
    allow_partial: read the complete shards of an unfinished folder (warnings).
    max_open: at most this many shards open at once in a process (default MAX_OPEN).
    on_corrupt: "refuse" (default) or "skip" a shard that fails its checks (module
    docstring: when each is checked, and what it costs). ``skipped``: the shards left out.

    Process-safe as described in the module docstring; ``close()`` (or ``with``)
    closes this process's handles, and garbage collection does too.
    """

    def __init__(self, folder, fields=None, transform=None, allow_partial: bool = False, max_open: int = 0,
                 on_corrupt: str = "refuse"):
        self.max_open = int(max_open) or MAX_OPEN
        if self.max_open < 1:
            raise ShardError(f"ShardDataset max_open: expected an integer >= 1 (0 for {MAX_OPEN}), got {max_open}")
        if on_corrupt not in ON_CORRUPT:
            raise ShardError(f"ShardDataset on_corrupt: expected 'refuse' or 'skip', got {on_corrupt!r}; pass "
                             "on_corrupt='refuse' (a corrupt shard is an error) or 'skip' (it is left out)")
        listing = open_folder(folder, allow_partial=allow_partial)
        self.on_corrupt, self.transform = on_corrupt, transform
        if on_corrupt == "skip":
            self.shards, counts, present, self.skipped = _verify_all(listing.shards)
        else:
            self.shards, self.skipped = listing.shards, ()
            counts, present = _counts_from_manifest(listing)
        self.frames = np.asarray(counts, dtype=np.int64)
        self._ends = np.cumsum(self.frames)
        self.fields = _resolve_fields(fields, present)
        self._readers: OrderedDict[int, _OpenShard] = OrderedDict()
        self._pid = os.getpid()
        self._checks = _SharedChecks(len(self.shards))

    def __len__(self) -> int:
        return int(self._ends[-1]) if len(self._ends) else 0

    def locate(self, index) -> tuple[int, int]:
        """(shard number in ``self.shards``, frame index in that shard) of item ``index``."""
        i = operator.index(index)
        n = len(self)
        if i < 0:
            i += n
        if not 0 <= i < n:
            raise IndexError(f"ShardDataset index {index} out of range for {n} frames")
        shard = int(np.searchsorted(self._ends, i, side="right"))
        return shard, i - int(self._ends[shard] - self.frames[shard])

    def __getitem__(self, index) -> dict:
        shard, local = self.locate(index)
        item = self._reader(shard).read(self.fields, local)
        return self.transform(item) if self.transform is not None else item

    def _reader(self, shard: int) -> _OpenShard:
        """This process's open reader of a shard, opened (and so verified) on first use. After
        a fork the handles inherited from the parent are dropped, never read through."""
        if self._pid != os.getpid():
            self._readers, self._pid = OrderedDict(), os.getpid()
        reader = self._readers.get(shard)
        if reader is not None:
            self._readers.move_to_end(shard)
            return reader
        while len(self._readers) >= self.max_open:   # the least recently read first
            self._readers.popitem(last=False)[1].close()
        self._checks.take(shard, self.shards[shard])
        reader = self._readers[shard] = _OpenShard(self.shards[shard], int(self.frames[shard]), self.fields)
        self._checks.record(shard, self.shards[shard])
        return reader

    def close(self) -> None:
        """Close the shards this process opened (a later read opens them again)."""
        readers, self._readers = self._readers, OrderedDict()
        if self._pid == os.getpid():
            for reader in readers.values():
                reader.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False

    def __del__(self):
        try:
            self.close()
        except Exception:  # noqa: BLE001 - interpreter shutdown, half-built object: nothing to do
            pass

    def __getstate__(self) -> dict:
        """Pickled without open handles (spawn workers open their own) and without the shared
        record (shared memory travels by fork only), but with what it knew verified."""
        state = dict(self.__dict__)
        state["_readers"], state["_pid"] = OrderedDict(), None
        state["_checks"] = [self._checks.known(k, path) for k, path in enumerate(self.shards)]
        return state

    def __setstate__(self, state: dict) -> None:
        known = state.pop("_checks")
        self.__dict__.update(state)
        self._checks = _SharedChecks(len(self.shards))
        for path, check in zip(self.shards, known):
            reuse_verification(path, check)  # taken only while the file's stat is the one verified

    def __repr__(self) -> str:
        return f"ShardDataset({len(self.shards)} shards, {len(self)} frames, fields={list(self.fields)})"


class _SharedChecks:
    """Which shards a process of this dataset verified: each one's stat key and digest
    (seal.verification) in memory shared with the processes forked from the one that made the
    dataset, so DataLoader's workers, forked anew each epoch from a parent that reads nothing,
    hash a shard once per run instead of once per worker and epoch. A process takes a record
    only while the file's stat is still the one recorded (seal.reuse_verification)."""

    RECORD = np.dtype([("key", "<i8", 5), ("digest", "S64")])

    def __init__(self, n: int):
        self._memory = multiprocessing.Array("b", max(n, 1) * self.RECORD.itemsize)  # zeroed, with a lock

    # A process killed while it held the shared lock (a DataLoader worker stopped mid-read) leaves
    # it held: the others wait this long, then do without the record (hash the shard themselves).
    LOCK_SECONDS = 2.0

    def known(self, shard: int, path) -> tuple | None:
        """This process's check of ``path``, else the shared record of shard ``shard``, else None."""
        mine = verification(path)
        if mine is not None:
            return mine
        lock = self._memory.get_lock()
        if not lock.acquire(timeout=self.LOCK_SECONDS):
            return None
        try:
            key, digest = np.frombuffer(self._memory.get_obj(), dtype=self.RECORD)[shard].tolist()
        finally:
            lock.release()
        return (tuple(key), digest.decode("ascii")) if digest else None

    def take(self, shard: int, path) -> None:
        reuse_verification(path, self.known(shard, path))

    def record(self, shard: int, path) -> None:
        mine = verification(path)  # None for a file changed within seal.RACY_SECONDS: hashed on every open
        lock = self._memory.get_lock()
        if mine is not None and lock.acquire(timeout=self.LOCK_SECONDS):
            try:
                np.frombuffer(self._memory.get_obj(), dtype=self.RECORD)[shard] = (mine[0], mine[1].encode("ascii"))
            finally:
                lock.release()


class _OpenShard:
    """A shard opened by ShardReader (every byte checked against its SHA-256 first), found to
    hold the frames and fields the dataset counted on, with its h5py datasets looked up once:
    a lookup per read costs more than reading a small field (the read path is HDF5's, as in
    ShardReader.read for one frame, Fletcher-32 included)."""

    def __init__(self, path, frames: int, fields: tuple):
        self.reader = ShardReader(path)
        self.pid = self.reader.pid  # the process that opened it
        try:
            _check_opened(self.reader, frames, fields)
            # ShardReader has no public handle on a field; its file is the one it verified.
            handle = self.reader._file  # noqa: SLF001
            self.sets = {name: (handle[name].asstr() if h5_is_string(handle[name]) else handle[name])
                         for name in fields}
        except BaseException:
            self.reader.close()
            raise

    def read(self, fields, j: int) -> dict:
        try:
            return {name: self.sets[name][j] for name in fields}
        except (*H5_ERRORS, UnicodeDecodeError):  # a chunk failing its Fletcher-32: the reader names shard and field
            return self.reader.read(fields, j)

    def close(self) -> None:
        self.sets = {}
        self.reader.close()


def _check_opened(reader: ShardReader, frames: int, fields: tuple) -> None:
    """A shard verified on its first read holds what construction counted on (from the manifest)."""
    have = int(reader.attrs["frames"])
    if have != frames:
        raise ShardError(f"{reader.path}: {have} frames in the shard, {MANIFEST} says {frames}; the manifest "
                         "does not match its shards: run `spm-data validate` on the folder")
    _missing_fields(reader.path, fields, reader.fields())


def _counts_from_manifest(listing) -> tuple[list, list]:
    """Frame counts of the shards, from the manifest (nothing hashed); a shard it gives no count
    for, and the first shard (the field list), opened and verified now. Also their fields."""
    listed = {e["file"]: e.get("frames") for e in (listing.manifest or {}).get("shards", [])}
    counts, present = [], []
    for k, path in enumerate(listing.shards):
        count = listed.get(path.name)
        if count is None or k == 0:
            with ShardReader(path) as reader:  # verified attrs and the field list; closed again
                count = int(reader.attrs["frames"]) if count is None else count
                present.append((path, reader.fields()))
        counts.append(count)
    return counts, present


def _verify_all(paths) -> tuple[tuple, list, list, tuple]:
    """(shards kept, their frame counts, their fields, shards skipped): every shard hashed and
    opened now; each one that fails is left out with a warning naming it and why."""
    hash_ahead(paths)  # two threads hash; the opens below find each shard checked
    kept, counts, present, skipped = [], [], [], []
    for path in paths:
        try:
            with ShardReader(path) as reader:
                counts.append(int(reader.attrs["frames"]))
                present.append((path, reader.fields()))
            kept.append(path)
        except ShardError as exc:
            skipped.append(path)
            warnings.warn(SpmWarning(f"{one_line(exc)}; skipped (on_corrupt='skip'): its frames are not "
                                     "in the dataset"), stacklevel=3)
    return tuple(kept), counts, present, tuple(skipped)


def _missing_fields(path, names, have) -> None:
    missing = [f for f in names if f not in have]
    if missing:
        raise ShardError(f"{path}: shard has no field {', '.join(map(repr, missing))} (asked for in fields=); "
                         "leave it out of fields, or read a folder whose shards all have it")


def _resolve_fields(fields, present) -> tuple:
    """The requested field names, checked: known to the schema and in every shard verified so far
    (``present``: (path, its fields) pairs)."""
    known = list(FIELDS) + list(OPTIONAL_FIELDS)
    if fields is None:
        common = set.intersection(*(set(p) for _, p in present)) if present else set()
        return tuple(f for f in known if f in common)
    names = (fields,) if isinstance(fields, str) else tuple(fields)
    unknown = [f for f in names if f not in known]
    if unknown or not names:
        raise ShardError(f"ShardDataset fields: expected names from spm_data.io.shards.FIELDS or OPTIONAL_FIELDS "
                         f"({', '.join(known)}), got {list(names)}; "
                         f"fix or drop {', '.join(map(repr, unknown)) or 'the empty list'}")
    for path, have in present:
        _missing_fields(path, names, have)
    return names

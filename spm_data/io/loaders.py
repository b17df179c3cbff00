"""Shard folders as training-loop datasets: a frame by index, read and verified.

``ShardDataset`` is a map-style dataset (``len`` and ``[i]``), the protocol
``torch.utils.data.DataLoader`` takes, without importing torch: spm does not
depend on it. Frames are read through ``spm_data.io.shards.ShardReader``, so every
read is verified (attributes and layout once per open, then HDF5's Fletcher-32
on every chunk read).

Process safety: an h5py handle must not cross a fork (pytorch/pytorch#11929).
The dataset opens no handle in ``__init__``; each process opens a shard on its
first read of it and keeps it, keyed by the process id, so a forked worker
(DataLoader's default on Linux) reopens instead of using its parent's handle,
and pickling (spawn workers) carries no handle at all. A process keeps at most
``max_open`` shards open (the least recently read is closed first), so a folder
of thousands of shards never runs into the open-file limit.
"""

from __future__ import annotations

import operator
import os
from collections import OrderedDict

import numpy as np

from spm_data.errors import ShardError
from spm_data.io.folders import open_folder
from spm_data.io.shards import FIELDS, OPTIONAL_FIELDS, ShardReader

MAX_OPEN = 64  # shards a process keeps open: well under the usual open-file limit (1024)


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
    fields: names from FIELDS / OPTIONAL_FIELDS; default every field all its shards
    have. transform: ``item -> item``, applied after reading (in the worker).
    allow_partial: read the complete shards of an unfinished folder (warnings).
    max_open: at most this many shards open at once in a process (default MAX_OPEN).

    Process-safe as described in the module docstring; ``close()`` (or ``with``)
    closes this process's handles, and garbage collection does too.
    """

    def __init__(self, folder, fields=None, transform=None, allow_partial: bool = False, max_open: int = 0):
        self.max_open = int(max_open) or MAX_OPEN
        if self.max_open < 1:
            raise ShardError(f"ShardDataset max_open: expected an integer >= 1 (0 for {MAX_OPEN}), got {max_open}")
        self.shards = open_folder(folder, allow_partial=allow_partial).shards
        self.transform = transform
        counts, present = [], []
        for path in self.shards:
            with ShardReader(path) as reader:  # verified attrs and the field list; closed again
                counts.append(int(reader.attrs["frames"]))
                present.append(reader.fields())
        self.frames = np.asarray(counts, dtype=np.int64)
        self._ends = np.cumsum(self.frames)
        self.fields = _resolve_fields(fields, self.shards, present)
        self._readers: OrderedDict[int, ShardReader] = OrderedDict()
        self._pid = os.getpid()

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

    def _reader(self, shard: int) -> ShardReader:
        """This process's open reader of a shard, opened on first use. After a fork
        the handles inherited from the parent are dropped, never read through."""
        if self._pid != os.getpid():
            self._readers, self._pid = OrderedDict(), os.getpid()
        reader = self._readers.get(shard)
        if reader is not None:
            self._readers.move_to_end(shard)
            return reader
        while len(self._readers) >= self.max_open:   # the least recently read first
            self._readers.popitem(last=False)[1].close()
        reader = self._readers[shard] = ShardReader(self.shards[shard])
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
        """Pickled without open handles (spawn workers open their own)."""
        state = dict(self.__dict__)
        state["_readers"], state["_pid"] = OrderedDict(), None
        return state

    def __repr__(self) -> str:
        return f"ShardDataset({len(self.shards)} shards, {len(self)} frames, fields={list(self.fields)})"


def _resolve_fields(fields, shards, present) -> tuple:
    """The requested field names, checked: known to the schema and in every shard."""
    known = list(FIELDS) + list(OPTIONAL_FIELDS)
    if fields is None:
        common = set.intersection(*(set(p) for p in present)) if present else set()
        return tuple(f for f in known if f in common)
    names = (fields,) if isinstance(fields, str) else tuple(fields)
    unknown = [f for f in names if f not in known]
    if unknown or not names:
        raise ShardError(f"ShardDataset fields: expected names from spm_data.io.shards.FIELDS or OPTIONAL_FIELDS "
                         f"({', '.join(known)}), got {list(names)}; "
                         f"fix or drop {', '.join(map(repr, unknown)) or 'the empty list'}")
    for path, have in zip(shards, present):
        missing = [f for f in names if f not in have]
        if missing:
            raise ShardError(f"{path}: shard has no field {', '.join(map(repr, missing))} (asked for in fields=); "
                             "leave it out of fields, or read a folder whose shards all have it")
    return names

"""What every pose estimator gets: a sequence of frames, one dict per frame.

``frames[i]`` is ``{"rgb": (H, W, 3) uint8, "mask": (H, W) bool, "K": (3, 3)
float64}`` (OpenCV pixel convention, spm_data/core/poses.py). ``mask`` is the
object's silhouette as the shard stores it (on occluded copies, the whole
silhouette; the rectangles are drawn into rgb). Images are read from the shards
lazily, a block of frames at a time, so a sequence of 100,000 frames costs no
memory until it is read; iterate in order for speed.

Besides, :class:`Frames` offers the cached per-frame features of
``spm_model.bench.feature_cache`` through :meth:`Frames.column` (``None`` when it has not
got them): the built-in methods use them when present and compute them from
the images otherwise, so they accept a plain list of dicts too.
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Sequence

import numpy as np

from spm_data.io.shards import read_shard

READ_BLOCK = 256   # frames read from a shard at a time
# What a method may read besides the images: features and intrinsics, never labels,
# classes or instances (a method's predict must not see the test poses).
FEATURE_COLUMNS = ("train_vector", "query_vector", "raw", "template", "K")
CACHED_BLOCKS = 4  # blocks kept in memory per sequence


class Frames(Sequence):
    """Lazy frames of a FeatureTable (every frame, or the rows ``index``)."""

    def __init__(self, table, index=None):
        self._table = table
        self.index = np.arange(len(table)) if index is None else np.asarray(index, dtype=np.int64)
        self._blocks: OrderedDict = OrderedDict()

    def __len__(self) -> int:
        return len(self.index)

    def __getitem__(self, i):
        if isinstance(i, slice) or (np.ndim(i) == 1):
            return Frames(self._table, self.index[i])
        row = int(self.index[i])
        shard, frame = str(self._table.shard[row]), int(self._table.frame[row])
        block = self._block(shard, frame // READ_BLOCK)
        j = frame % READ_BLOCK
        return {"rgb": block["rgb"][j], "mask": block["mask"][j] > 0, "K": self._table.K[row]}

    def _block(self, shard: str, b: int) -> dict:
        key = (shard, b)
        if key not in self._blocks:
            self._blocks[key] = read_shard(shard, ("rgb", "mask"), frames=slice(b * READ_BLOCK, (b + 1) * READ_BLOCK))
            if len(self._blocks) > CACHED_BLOCKS:
                self._blocks.popitem(last=False)
        self._blocks.move_to_end(key)
        return self._blocks[key]

    def column(self, name: str):
        """A cached per-frame feature of FEATURE_COLUMNS (len(self), ...), or None when
        the table lacks it or ``name`` is not a feature (labels are never served)."""
        values = self._table.arrays.get(name) if name in FEATURE_COLUMNS else None
        return None if values is None else values[self.index]

    def __getstate__(self):  # picklable for process pools: without the image cache
        return {"table": self._table, "index": self.index}

    def __setstate__(self, state):
        self.__init__(state["table"], state["index"])


def column(frames, name: str, compute) -> np.ndarray:
    """``frames.column(name)`` when the sequence has it, else ``compute(frame)``
    stacked over the frames (for plain lists of frame dicts)."""
    get = getattr(frames, "column", None)
    values = get(name) if get is not None else None
    if values is not None:
        return values
    return np.stack([compute(f) for f in frames]) if len(frames) else np.zeros((0,))

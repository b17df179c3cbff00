"""What every pose estimator gets: sequences of frames, one dict per frame.

Training frames (``fit(frames, poses)``, :class:`Frames`): ``frames[i]`` is a
mapping with
- ``rgb`` (H, W, 3) uint8;
- ``mask`` (H, W) bool, the object's *visible* pixels (on occluded copies and
  cluttered frames, the silhouette minus what hides it: what a segmenter gives);
- ``K`` (3, 3) float64 (OpenCV pixel convention, spm_data/core/poses.py);
- ``depth`` (H, W) float32 metres (camera z of the nearest surface, 0 where none),
  read only when asked for;
- ``sequence`` int, one id per camera path (a shard's instance), and
  ``path_index`` int, the frame's place on it (on grid walks, consecutive
  indices are neighbouring views 5° apart).
Their poses come as ``fit``'s second argument.

Test frames (``predict(frames)``, :class:`CameraFrames`): ``frames[i]`` is
``{"rgb", "mask", "K"}`` and nothing else: what a camera and a segmenter give.
They carry no label, class, instance, pose, shard or path in any attribute, and
come in a seeded random order (the protocol puts the predictions back).

Both offer cached image features through ``frames.column(name)``
(FEATURE_COLUMNS; ``None`` when absent): the built-in methods use them when
present and compute them from the images otherwise, so they accept a plain
list of dicts too. Test frames offer only features computed from the image
alone (``query_vector``, ``raw``, ``template``, ``K``).
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Mapping, Sequence
from functools import lru_cache

import numpy as np

from spm_data.io.shards import read_shard, shard_layout

READ_BLOCK = 256   # frames read from a shard at a time
# What a method may read besides the images: features and intrinsics, never labels.
FEATURE_COLUMNS = ("train_vector", "query_vector", "raw", "template", "K")
# Of those, what a test frame may offer: computed from its own image and mask alone
# (train_vector uses the frame's path neighbours: where it lies on a camera path).
CAMERA_COLUMNS = ("query_vector", "raw", "template", "K")
TRAIN_KEYS = ("rgb", "mask", "K", "depth", "sequence", "path_index")
CAMERA_KEYS = ("rgb", "mask", "K")
CACHED_BLOCKS = 4  # blocks kept in memory per sequence
CHUNK_BYTES = 256 << 20  # test frames handed to predict at a time, at most (images in memory)


@lru_cache(maxsize=4096)
def visible_field(shard: str) -> str:
    """The field holding what a camera sees of the object: ``visible_mask`` where the shard
    has one (occluded copies, cluttered frames), else ``mask`` (nothing hides the object)."""
    return "visible_mask" if "visible_mask" in shard_layout(shard) else "mask"


def camera_paths(table, index) -> np.ndarray:
    """(len(index),) str: the camera path of each frame ``index`` of a feature table, one per
    (shard, instance): what ``sequence`` numbers and what a method's ``Needs.sequences`` counts."""
    return np.char.add(np.char.add(table.shard[index].astype(str), "#"), table.instance_id[index].astype(str))


class _Frame(Mapping):
    """One training frame: its fields read on first use (depth only when asked for)."""

    def __init__(self, frames: "Frames", i: int):
        self._frames, self._i = frames, i

    def __getitem__(self, key):
        if key not in TRAIN_KEYS:
            raise KeyError(key)
        return self._frames._value(self._i, key)

    def __contains__(self, key) -> bool:  # Mapping's would read the field to find out
        return key in TRAIN_KEYS

    def __iter__(self):
        return iter(TRAIN_KEYS)

    def __len__(self) -> int:
        return len(TRAIN_KEYS)


class Frames(Sequence):
    """Lazy training frames of a feature table (spm_model/bench/feature_cache.py), the rows
    ``index`` (default all): only those rows' image locations, K, camera paths and the
    image-derived feature columns are kept, never the table's labels."""

    def __init__(self, table, index=None):
        index = np.arange(len(table)) if index is None else np.asarray(index, dtype=np.int64)
        self._shard = table.shard[index]
        self._frame = table.frame[index]
        self._K = table.K[index]
        self._path_index = table.path_index[index].astype(np.int64)
        _, self._sequence = np.unique(camera_paths(table, index), return_inverse=True)
        self._features = {k: table.arrays[k] for k in FEATURE_COLUMNS if k in table.arrays}
        self._rows = index
        self._blocks: OrderedDict = OrderedDict()

    def __len__(self) -> int:
        return len(self._rows)

    def __getitem__(self, i):
        if isinstance(i, slice) or np.ndim(i) == 1:
            sub = object.__new__(Frames)
            sub.__dict__.update({k: (v[i] if isinstance(v, np.ndarray) else v) for k, v in self.__dict__.items()})
            sub._blocks = OrderedDict()
            return sub
        return _Frame(self, int(range(len(self))[i]))

    def _value(self, i: int, key: str):
        if key == "K":
            return self._K[i]
        if key in ("sequence", "path_index"):
            return int((self._sequence if key == "sequence" else self._path_index)[i])
        shard, frame = str(self._shard[i]), int(self._frame[i])
        fields = ("depth",) if key == "depth" else ("rgb", visible_field(shard))
        block = self._block(shard, frame // READ_BLOCK, fields)
        j = frame % READ_BLOCK
        if key == "depth":
            return block["depth"][j]
        return block["rgb"][j] if key == "rgb" else block[fields[1]][j] > 0

    def _block(self, shard: str, b: int, fields: tuple) -> dict:
        key = (shard, b, fields)
        if key not in self._blocks:
            self._blocks[key] = read_shard(shard, fields, frames=slice(b * READ_BLOCK, (b + 1) * READ_BLOCK))
            if len(self._blocks) > CACHED_BLOCKS:
                self._blocks.popitem(last=False)
        self._blocks.move_to_end(key)
        return self._blocks[key]

    def column(self, name: str):
        """A cached per-frame feature of FEATURE_COLUMNS (len(self), ...), or None when
        the table lacks it or ``name`` is not a feature (labels are never served)."""
        if name == "K":
            return self._K
        values = self._features.get(name) if name in FEATURE_COLUMNS else None
        return None if values is None else values[self._rows]

    def __getstate__(self):
        """Picklable for the methods' processes: these frames' rows of the feature columns only
        (nothing of the table's other frames), without the image cache."""
        state = {k: v for k, v in self.__dict__.items() if k not in ("_blocks", "_features", "_rows")}
        state["_features"] = {k: v[self._rows] for k, v in self._features.items()}
        state["_rows"] = np.arange(len(self._rows))
        return state

    def __setstate__(self, state):
        self.__dict__.update(state)
        self._blocks = OrderedDict()


class CameraFrames(Sequence):
    """Test frames as a camera gives them: images, visible masks and K held in memory, in
    the order given, with the image-derived columns of CAMERA_COLUMNS. Nothing else."""

    def __init__(self, rgb: list, mask: list, K: np.ndarray, columns: dict):
        self._rgb, self._mask, self._K = rgb, mask, np.asarray(K, dtype=np.float64)
        self._columns = {k: v for k, v in columns.items() if k in CAMERA_COLUMNS}

    def __len__(self) -> int:
        return len(self._rgb)

    def __getitem__(self, i):
        if isinstance(i, slice) or np.ndim(i) == 1:
            idx = range(len(self))[i] if isinstance(i, slice) else np.asarray(i)
            return CameraFrames([self._rgb[j] for j in idx], [self._mask[j] for j in idx], self._K[list(idx)],
                                {k: v[list(idx)] for k, v in self._columns.items()})
        return {"rgb": self._rgb[i], "mask": self._mask[i], "K": self._K[i]}

    def column(self, name: str):
        return self._K if name == "K" else self._columns.get(name)


def read_camera_frames(table, rows: np.ndarray) -> CameraFrames:
    """The test frames ``rows`` of a feature table, in that order, as CameraFrames: each
    shard read once, a block at a time, verified (spm_data.io.shards.read_shard)."""
    rows = np.asarray(rows, dtype=np.int64)
    rgb, mask = [None] * len(rows), [None] * len(rows)
    shards, frames = table.shard[rows], table.frame[rows]
    for shard in dict.fromkeys(shards.tolist()):
        where = np.flatnonzero(shards == shard)
        field = visible_field(shard)
        for b in np.unique(frames[where] // READ_BLOCK):
            sel = where[frames[where] // READ_BLOCK == b]
            block = read_shard(shard, ("rgb", field), frames=slice(int(b) * READ_BLOCK, (int(b) + 1) * READ_BLOCK))
            for k in sel:
                j = int(frames[k]) % READ_BLOCK
                rgb[k], mask[k] = block["rgb"][j], block[field][j] > 0
    columns = {k: table.arrays[k][rows] for k in CAMERA_COLUMNS if k in table.arrays and k != "K"}
    return CameraFrames(rgb, mask, table.K[rows], columns)


def camera_chunks(table, rows: np.ndarray):
    """``rows`` split into runs whose images take at most CHUNK_BYTES (one run at least one frame)."""
    per_frame = max(1, int(np.max(table.width[rows])) ** 2 * 4) if len(rows) else 1
    step = max(1, CHUNK_BYTES // per_frame)
    return [rows[i: i + step] for i in range(0, len(rows), step)]


def cached_column(frames, name: str):
    """``frames.column(name)`` when the sequence has it (Frames, CameraFrames), else None (a plain
    list of frame dicts)."""
    get = getattr(frames, "column", None)
    return get(name) if get is not None else None


def column(frames, name: str, compute) -> np.ndarray:
    """``frames.column(name)`` when the sequence has it, else ``compute(frame)``
    stacked over the frames (for plain lists of frame dicts)."""
    values = cached_column(frames, name)
    if values is not None:
        return values
    return np.stack([compute(f) for f in frames]) if len(frames) else np.zeros((0,))

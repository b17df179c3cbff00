"""What N3M and SIFT + PnP compute alike, computed once per process: their 3-D points, the FLANN
index over the points' descriptors, and each test image's nearest stored descriptors.

The two methods share their SIFT (n3m_points.remembered_sift_features), and with their
default parameters also everything built from it: merging the lifted keypoints into 3-D
points, the index, and the k-nearest-neighbour search of every test image (a benchmark's
split runs both in one process, spm_model/bench/isolation.py). A profile of one ``loco``
split (960 training and 480 test pyrender frames, 2026-11-28) spent 17 of its 70 s on these
twice. Each is remembered under a content key (spm_model/base/feature_memo.content_key) of
its inputs and the parameters it depends on, so it is the method's own deterministic
function, remembered: results are identical with or without it, and nothing is remembered
that the inputs do not determine. Entries are kept in memory only, the oldest forgotten
past a count, and none when ``SPM_FEATURE_MEMO_MB`` is 0 (the feature memo's switch). A point set
keeps its observations' descriptors alive (128 bytes a keypoint: about 90 MB for 2,400 training
frames of 300 keypoints); a benchmark's split process ends with its split.
"""

from __future__ import annotations

from collections import OrderedDict
from typing import Callable

import numpy as np

from spm_model.base.feature_memo import budget_bytes, content_key

POINTS_KEPT = 2      # point sets (one per training set and parameters): N3M's and SIFT + PnP's
INDEXES_KEPT = 2
NEIGHBOURS_KEPT = 4096   # test images' searches: a whole test chunk of one method, for the next

_points: OrderedDict = OrderedDict()
_indexes: OrderedDict = OrderedDict()
_neighbours: OrderedDict = OrderedDict()
_stats = {"hits": 0, "misses": 0}


def _remembered(table: OrderedDict, most: int, key: bytes, compute: Callable):
    """``compute()``, remembered in ``table`` under ``key`` (at most ``most`` entries, the oldest
    forgotten); every array in what it returns is made read-only, as it is shared."""
    if budget_bytes() <= 0:
        return compute()
    if key in table:
        _stats["hits"] += 1
        table.move_to_end(key)
        return table[key]
    _stats["misses"] += 1
    value = compute()
    _freeze(value)
    table[key] = value
    while len(table) > most:
        table.popitem(last=False)
    return value


def _freeze(value) -> None:
    if isinstance(value, np.ndarray):
        value.flags.writeable = False
    elif isinstance(value, dict):
        for item in value.values():
            _freeze(item)
    elif isinstance(value, (list, tuple)):
        for item in value:
            _freeze(item)


def observations_key(params: tuple, obs: dict) -> bytes:
    """The content key of lifted observations (SiftPoints._observe's dict) and the merging
    parameters ``params``: everything the 3-D points are computed from."""
    views = obs["views"]
    arrays = [obs[k] for k in ("xyz", "desc", "view", "object", "footprint")]
    arrays += [np.asarray(views["R"]), np.asarray(views["t"]), np.asarray(views["object"]),
               np.asarray(views["shape"]), np.asarray(views["K"])] + list(views["depth"])
    return content_key(("sift-points",) + tuple(params), *arrays)


def remembered_points(key: bytes, compute: Callable):
    """``compute()`` (the per-object points and the stored database), remembered under ``key``."""
    return _remembered(_points, POINTS_KEPT, key, compute)


def remembered_index(descriptors: np.ndarray, build: Callable) -> tuple[bytes, object]:
    """(the content key of ``descriptors``, ``build(descriptors)``: their FLANN index), the
    index built once per process for equal descriptors."""
    key = content_key(("flann-index",), descriptors)
    return key, _remembered(_indexes, INDEXES_KEPT, key, lambda: build(descriptors))


def remembered_neighbours(index_key: bytes, queries: np.ndarray, k: int, checks: int,
                          search: Callable) -> tuple[np.ndarray, np.ndarray]:
    """``search()`` (idx, dist of the ``k`` nearest indexed rows of ``queries``), remembered
    under the index's key, the queries' bytes, ``k`` and ``checks``."""
    key = content_key(("flann-knn", index_key, int(k), int(checks)), queries)
    return _remembered(_neighbours, NEIGHBOURS_KEPT, key, search)


def memo_stats() -> dict:
    """{"hits", "misses", "points", "indexes", "neighbours"} of this process."""
    return {**_stats, "points": len(_points), "indexes": len(_indexes), "neighbours": len(_neighbours)}


def clear_memo() -> None:
    for table in (_points, _indexes, _neighbours):
        table.clear()
    _stats.update(hits=0, misses=0)


class RememberedSearches:
    """A FLANN index (``knnSearch`` as n3m_points.knn calls it) whose searches are remembered
    (:func:`remembered_neighbours`): N3M and SIFT + PnP search each test image once between them."""

    def __init__(self, key: bytes, index):
        self.key, self.index = key, index

    def knnSearch(self, queries, k, params):  # noqa: N802 - OpenCV's name, called as OpenCV's
        def search():
            idx, d2 = self.index.knnSearch(queries, k, params=params)
            return np.asarray(idx), np.asarray(d2)
        return remembered_neighbours(self.key, queries, k, int(params.get("checks", 32)), search)

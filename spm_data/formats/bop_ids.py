"""Which BOP object, scene and image each frame of a shard folder becomes: the one rule the
export (bop_export.py) and the results file (bop_results.py) share.

Scenes: one per target object, ``scene_id = obj_id - 1``; images are numbered 0, 1, ... in each
scene in the folder's frame order (manifest order, then frame index).

Object ids: the folder's objects sorted by (class name, instance number, instance name) are
numbered 1, 2, ...; with ``ids_from`` (a previous export, or its objects.json), the objects it
lists keep their ids and new ones are numbered after its largest.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from spm_data.io.folders import open_folder
from spm_data.io.shards import read_shard


@dataclass(frozen=True)
class FrameIds:
    """Per frame of a folder, in its frame order: ``obj_id``, ``scene_id``, ``im_id`` (N,) int64."""
    obj_id: np.ndarray
    scene_id: np.ndarray
    im_id: np.ndarray


def frame_names(shards):
    """(class name, instance number, instance name) of every frame of ``shards``."""
    for path in shards:
        d = read_shard(path, ["class_name", "instance_id", "instance_name"])
        yield from zip(map(str, d["class_name"]), map(int, d["instance_id"]), map(str, d["instance_name"]))


def object_ids(objects, ids_from=None) -> dict[tuple, int]:
    """(class name, instance name) -> obj_id for ``objects``, an iterable of (class name, instance
    number, instance name), by the module's rule (sorted; ``ids_from`` keeps a previous export's)."""
    from spm_data.formats.bop_export import read_objects

    given = {(v["class"], v["instance"]): k for k, v in read_objects(ids_from).items()} if ids_from else {}
    ids, next_id = {}, max(given.values(), default=0) + 1
    for cls, _, name in sorted(set(objects)):
        if (cls, name) in given:
            ids[(cls, name)] = given[(cls, name)]
        elif (cls, name) not in ids:
            ids[(cls, name)], next_id = next_id, next_id + 1
    return ids


def frame_ids(folder, ids_from=None, allow_partial: bool = False) -> FrameIds:
    """The BOP (obj_id, scene_id, im_id) of every frame of ``folder`` (a shard folder, read by
    its manifest), as ``export bop`` of that folder (with the same ``ids_from``) numbers them."""
    shards = open_folder(folder, allow_partial=allow_partial).shards
    names = list(frame_names(shards))
    ids = object_ids(names, ids_from)
    obj = np.asarray([ids[(cls, name)] for cls, _, name in names], dtype=np.int64)
    im = np.zeros(len(obj), dtype=np.int64)
    seen: dict[int, int] = {}
    for k, o in enumerate(obj.tolist()):
        im[k] = seen.get(o, 0)
        seen[o] = im[k] + 1
    return FrameIds(obj_id=obj, scene_id=obj - 1, im_id=im)

"""Which BOP object, scene and image each frame of a shard folder becomes: the one rule the
export (bop/export.py) and the results file (bop/results.py) share.

Objects are meshes: a frame's target is identified by the digest of the mesh it was drawn from
(core/mesh_store.py), so two meshes under one class and instance name are two objects (their
``instance`` names get ``~`` and the digest's first 8 digits), and one mesh under two names is
one object (named by the first name, sorted; ``names`` lists all). A frame without a mesh
(imported) is identified by its (class, instance) name. A 3-D distractor is the pool mesh it was
drawn from at the size it was drawn, an object of its own (a BOP model has one size), its
``instance`` name its pool name and that size (``box-10000@73.1mm``; ``~`` and the digest's first
8 digits where two meshes share the pool name).

Object ids: the targets sorted by (class name, instance number, instance name, digest) are
numbered 1, 2, ..., then the distractors (sorted by name, digest, size), so leaving the
distractors out renumbers nothing. With ``ids_from`` (a previous export, or its objects.json)
the objects it lists keep their ids (matched by digest, or by name for entries without one) and
new ones are numbered after its largest.

Scenes: one per target object, ``scene_id = obj_id - 1``; images are numbered 0, 1, ... in each
scene in the folder's frame order (manifest order, then frame index).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from spm_data.errors import SpmError
from spm_data.core.shard_meshes import FrameMeshes
from spm_data.io.folders import open_folder
from spm_data.io.shards import read_attrs, read_shard, shard_layout

OBJECTS_FILE = "objects.json"   # obj_id -> entry (:func:`object_entry`), at the export's root
DISTRACTOR_CLASS = "distractor"


@dataclass(frozen=True)
class FrameIds:
    """Per frame of a folder, in its frame order: ``obj_id``, ``scene_id``, ``im_id`` (N,) int64."""
    obj_id: np.ndarray
    scene_id: np.ndarray
    im_id: np.ndarray


@dataclass
class Objects:
    """A folder's objects: identity -> obj_id and -> objects.json entry; per frame, the target's
    identity (``targets``, N) and its distractors' ((identity, pool index k, size) lists)."""
    ids: dict = field(default_factory=dict)
    entries: dict = field(default_factory=dict)
    targets: list = field(default_factory=list)
    distractors: list = field(default_factory=list)


def save_objects(root, names: dict) -> Path:
    """The export's objects.json at ``root``: obj_id -> entry (:func:`load_objects` reads it back)."""
    path = Path(root) / OBJECTS_FILE
    path.write_text(json.dumps({str(k): names[k] for k in sorted(names)}, indent=1))
    return path


def load_objects(path) -> dict[int, dict]:
    """obj_id -> entry ({"class", "instance", "instance_id"}, and "mesh", "names", "role",
    "scale_m" where known) from an export's objects.json (``path``: the file or the export
    folder); SpmError naming the file when it is missing or malformed."""
    path = Path(path)
    path = path / OBJECTS_FILE if path.is_dir() else path
    try:
        table = json.loads(path.read_text())
        return {int(k): {**v, "class": str(v["class"]), "instance": str(v["instance"]),
                         "instance_id": int(v["instance_id"])} for k, v in table.items()}
    except FileNotFoundError:
        raise SpmError(f"{path}: no such file; give an export folder or its {OBJECTS_FILE}") from None
    except (OSError, ValueError, TypeError, KeyError, AttributeError) as exc:
        raise SpmError(f"{path}: not an {OBJECTS_FILE} (obj_id -> class, instance, instance_id): "
                       f"{type(exc).__name__}: {exc}") from None


def _target_identity(cls: str, name: str, digest: str) -> tuple:
    return ("mesh", digest) if digest else ("name", cls, name)


def scan_objects(shards, meshes: FrameMeshes, distractors: bool = True) -> Objects:
    """Every frame's target identity and (with ``distractors``) its 3-D distractors', named."""
    found = Objects()
    names: dict[tuple, set] = {}       # identity -> {(class, instance id, instance name)}
    for path in shards:
        layout, attrs = shard_layout(path), read_attrs(path)
        d = read_shard(path, ["class_name", "instance_id", "instance_name"] + (["mesh"] if "mesh" in layout else []))
        for cls, inst, name, digest in zip(d["class_name"], d["instance_id"], d["instance_name"],
                                           meshes.targets(attrs, d)):
            identity = _target_identity(str(cls), str(name), digest)
            names.setdefault(identity, set()).add((str(cls), int(inst), str(name)))
            found.targets.append(identity)
        placed = distractors and "distractor_mesh" in layout and "distractor_size" in layout
        found.distractors += _distractors(path, attrs, meshes, names) if placed else [[] for _ in d["class_name"]]
    _name_objects(found, names)
    return found


def _distractors(path, attrs: dict, meshes: FrameMeshes, names: dict) -> list:
    pool, pool_names = meshes.pool(attrs), json.loads(attrs.get("distractor_meshes") or "[]")
    d = read_shard(path, ["distractor_mesh", "distractor_size"])
    frames = []
    for row, sizes in zip(d["distractor_mesh"], d["distractor_size"]):
        placed = []
        for k, (index, size) in enumerate(zip(row.tolist(), sizes.tolist())):
            if index >= 0 and index < len(pool) and pool[index]:
                identity = ("distractor", pool[index], float(size))
                names.setdefault(identity, set()).add((DISTRACTOR_CLASS, index, Path(pool_names[index]).stem))
                placed.append((identity, k, float(size)))
        frames.append(placed)
    return frames


def _size_labels(sizes) -> dict[float, str]:
    """Each of ``sizes`` (metres; one pool mesh's drawn sizes) as a label in mm, to the fewest
    decimals that tell them apart (``@73.1mm``), else the float itself."""
    for decimals in (1, 3, 6):
        labels = {s: f"@{s * 1000:.{decimals}f}mm" for s in sizes}
        if len(set(labels.values())) == len(labels):
            return labels
    return {s: f"@{s!r}m" for s in sizes}


def _name_objects(found: Objects, names: dict) -> None:
    by_name: dict[tuple, set] = {}
    for identity, seen in names.items():
        for cls, _, name in seen:
            by_name.setdefault((cls, name), set()).add(identity)
    sizes: dict[str, set] = {}   # a distractor mesh's digest -> its drawn sizes: each its own object
    for identity in names:
        if identity[0] == "distractor":
            sizes.setdefault(identity[1], set()).add(identity[2])
    labels = {digest: _size_labels(sorted(s)) for digest, s in sizes.items()}
    for identity, seen in names.items():
        cls, inst, name = min(seen)
        entry = {"class": cls, "instance": name, "instance_id": inst}
        if identity[0] != "name":
            meshes = {i[1] for i in by_name[(cls, name)]}
            if len(meshes) > 1:   # one name, several meshes: the name says which
                entry["instance"] = f"{name}~{identity[1][:8]}"
            if identity[0] == "distractor":   # one mesh, several sizes: the name says its size
                entry["instance"] += labels[identity[1]][identity[2]]
            entry["mesh"] = identity[1]
        if len(seen) > 1:
            entry["names"] = [f"{c}/{n}" for c, _, n in sorted(seen)]
        if identity[0] == "distractor":
            entry.update(role="distractor", scale_m=identity[2])
        found.entries[identity] = entry


def number_objects(found: Objects, ids_from=None) -> None:
    """Fill ``found.ids`` by the module's rule."""
    given = load_objects(ids_from) if ids_from else {}
    by_mesh = {(v.get("mesh"), v.get("scale_m")): k for k, v in given.items() if v.get("mesh")}
    by_name = {(v["class"], v["instance"]): k for k, v in given.items() if not v.get("mesh")}
    next_id = max(given, default=0) + 1

    def order(identity):
        e = found.entries[identity]
        return (identity[0] == "distractor", e["class"], e["instance_id"], e["instance"], identity[1:])

    for identity in sorted(found.entries, key=order):
        e = found.entries[identity]
        known = by_mesh.get((e.get("mesh"), e.get("scale_m"))) if e.get("mesh") else None
        known = known or by_name.get((e["class"], e["instance"]))
        if known is None:
            known, next_id = next_id, next_id + 1
        found.ids[identity] = known


def folder_objects(folder, ids_from=None, *, allow_partial=False, spec_dir=None, distractors=True):
    """(shards, FrameMeshes, numbered Objects) of a shard folder."""
    shards = open_folder(folder, allow_partial=allow_partial).shards
    meshes = FrameMeshes(shards[0].parent if shards else folder, spec_dir=spec_dir)
    found = scan_objects(shards, meshes, distractors)
    number_objects(found, ids_from)
    return shards, meshes, found


def image_ids(obj_ids) -> np.ndarray:
    """(N,) int64: each frame's image number in its scene (0, 1, ... per obj_id, in order)."""
    im, seen = np.zeros(len(obj_ids), dtype=np.int64), {}
    for k, o in enumerate(np.asarray(obj_ids).tolist()):
        im[k] = seen.get(o, 0)
        seen[o] = im[k] + 1
    return im


def frame_ids(folder, ids_from=None, allow_partial: bool = False) -> FrameIds:
    """The BOP (obj_id, scene_id, im_id) of every frame's target in ``folder`` (a shard folder,
    read by its manifest), as ``export bop`` of that folder (with the same ``ids_from``) numbers them."""
    _, _, found = folder_objects(folder, ids_from, allow_partial=allow_partial, distractors=False)
    obj = np.asarray([found.ids[i] for i in found.targets], dtype=np.int64)
    return FrameIds(obj_id=obj, scene_id=obj - 1, im_id=image_ids(obj))

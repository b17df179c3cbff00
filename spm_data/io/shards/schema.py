"""The shard schema: fields, their dtypes and per-frame shapes, required attributes (docs/shard-format.md)."""

from __future__ import annotations

import numpy as np

from spm_data.errors import ShardError

SCHEMA_VERSION = 3  # 2: every dataset checksummed (Fletcher-32), strings fixed-length; 3: whole-file SHA-256 (seal.py)


SHARD_SUFFIX = ".h5"


MANIFEST = "manifest.json"
MISSING = "missing"  # manifest key: the planned shards the run that wrote it did not make


# name -> (dtype, per-frame shape; "H", "W", "R" (rectangles), "D" (distractors) and "L" (lights)
# are filled in per shard)
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


# Fields of FIELDS a shard may lack: depth, where an import has none (every render has it); a read
# of it then gives zeros, no surface measured (reader.py), what imported shards stored before.
MAY_BE_ABSENT = ("depth",)


OPTIONAL_FIELDS: dict[str, tuple[str, tuple]] = {
    "visible_mask": ("uint8", ("H", "W")),   # object minus occluders (spm-data occlude)
    "source_shard": ("str", ()),             # the shard a derived frame came from
    "source_frame": ("int64", ()),           # its frame index there
    "mesh": ("str", ()),                     # SHA-256 of the target's mesh in the folder's meshes/; "" none
    # [outputs] (opt-in)
    "instances": ("uint8", ("H", "W")),      # 0 nothing, 1 the target, 2 + k distractor k
    "normals": ("float16", ("H", "W", 3)),   # camera frame (OpenCV), unit; 0 where nothing was hit
    "coords": ("float16", ("H", "W", 3)),    # object-frame metres of each visible target pixel; else 0
    # [distractors]
    "visible_target": ("float32", ()),       # the drawn visible fraction of the target
    "distractor_mesh": ("int64", ("D",)),    # index into the attribute distractor_meshes; -1: none
    "distractor_R": ("float64", ("D", 3, 3)),  # distractor -> camera rotation (OpenCV)
    "distractor_t": ("float64", ("D", 3)),   # metres
    "distractor_size": ("float64", ("D",)),  # its longest bounding-box side, metres
    # [randomize]
    "lights": ("float32", ("L", 7)),         # direction (camera frame) 3, colour 3, strength; zero rows unused
    "material": ("float32", (5,)),           # base-colour factor 3, roughness, metallic
    "ambient": ("float32", ()),              # 0..1 of white
    "background": ("str", ()),               # the frame's background kind (randomize.backgrounds or the spec's)
}


IMAGE_FIELDS = ("rgb", "depth", "mask", "visible_mask", "instances", "normals", "coords")
SIZED_DIMS = ("R", "D", "L")  # per-frame list lengths, read from the arrays (check_arrays)
SIZED_FIELDS = tuple(f for f, (_, shape) in {**FIELDS, **OPTIONAL_FIELDS}.items() if set(shape) & set(SIZED_DIMS))


REQUIRED_ATTRS = ("schema_version", "frames", "renderer", "seed")


SOURCES = ("synthetic", "coil100", "coil20", "cvl", "folder", "bop", "nerf")


def expected_shape(field: str, n: int, h: int, w: int, dims=None) -> tuple:
    """(n,) + the per-frame shape of ``field``; ``dims``: the sizes of "R", "D", "L" (default 1)."""
    spec = {**FIELDS, **OPTIONAL_FIELDS}[field][1]
    sizes = {"H": h, "W": w, **{d: 1 for d in SIZED_DIMS}, **(dims or {})}
    return (n,) + tuple(sizes.get(d, d) for d in spec)


def check_arrays(arrays: dict) -> tuple[int, int, int]:
    """Validate a shard's arrays against the schema; returns (N, H, W)."""
    missing = [f for f in FIELDS if f not in arrays and f not in MAY_BE_ABSENT]
    if missing:
        raise ShardError(f"shard arrays are missing {', '.join(missing)}")
    unknown = [f for f in arrays if f not in FIELDS and f not in OPTIONAL_FIELDS]
    if unknown:
        raise ShardError(f"shard arrays have unknown fields {', '.join(unknown)}")
    n, h, w = np.asarray(arrays["rgb"]).shape[:3]
    dims = {}
    for field, value in arrays.items():  # each sized dimension from the first field that has it
        shape = {**FIELDS, **OPTIONAL_FIELDS}.get(field, ("", ()))[1]
        for k, d in enumerate(shape):
            if d in SIZED_DIMS and d not in dims and np.ndim(value) > k + 1:
                dims[d] = np.shape(value)[k + 1]
    for field, value in arrays.items():
        dtype = {**FIELDS, **OPTIONAL_FIELDS}[field][0]
        shape = expected_shape(field, n, h, w, dims)
        got = np.shape(value)
        if got != shape:
            raise ShardError(f"shard field {field!r}: expected shape {shape}, got {got}")
        if dtype != "str" and np.asarray(value).dtype != np.dtype(dtype):
            raise ShardError(f"shard field {field!r}: expected dtype {dtype}, got {np.asarray(value).dtype}")
    return n, h, w

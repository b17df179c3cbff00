"""HDF5 shards and the per-folder manifest: one writer, one reader (docs/shard-format.md).

A shard is written to a hidden ``.NAME.partial`` file in the same folder and
``os.replace``-d to ``NAME`` once complete, so a shard that exists is whole.
``manifest.json`` is written last, the same way.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import zlib
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from spm_data.errors import ShardError

SCHEMA_VERSION = 1
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


def encode_chunk(frame: np.ndarray) -> bytes:
    """One frame as HDF5's filters would store it: byte shuffle (multi-byte
    dtypes only), then deflate level 1 (zlib format). Deterministic."""
    a = np.ascontiguousarray(frame)
    if a.dtype.itemsize > 1:
        a = a.view(np.uint8).reshape(-1, a.dtype.itemsize).T  # HDF5 shuffle: byte planes
    return zlib.compress(np.ascontiguousarray(a).tobytes(), GZIP_LEVEL)


def _write_image_field(f, field: str, value: np.ndarray, pool) -> None:
    """Compress frames on ``pool``'s threads (zlib releases the GIL; h5py's own
    filter pipeline does not) and store them as the chunks of a standard
    gzip (+ shuffle) dataset, so any HDF5 reader decodes them."""
    ds = f.create_dataset(field, shape=value.shape, dtype=value.dtype, chunks=(1,) + value.shape[1:],
                          compression="gzip", compression_opts=GZIP_LEVEL, shuffle=value.dtype.itemsize > 1,
                          track_times=False)
    zero = (0,) * (value.ndim - 1)
    for i, chunk in enumerate(pool.map(encode_chunk, value)):
        ds.id.write_direct_chunk((i,) + zero, chunk)


def partial_path(path: Path) -> Path:
    return path.with_name(PARTIAL_PREFIX + path.name + PARTIAL_SUFFIX)


def write_shard(path, arrays: dict, attrs: dict, copy_from=None) -> Path:
    """Write one shard atomically (temporary name, fsync, ``os.replace``).

    arrays: every field of FIELDS (and any of OPTIONAL_FIELDS), first axis N
    frames. attrs: file attributes (str, int, float); ``schema_version`` and
    ``frames`` are set here. Image fields are chunked one frame per chunk and
    compressed with gzip level 1 after byte shuffling: deterministic (LZF is not:
    liblzf leaves its hash table uninitialised, so equal arrays could give
    different bytes), readable by every HDF5 build, and about as fast.

    copy_from: ``(shard path, fields)``: fields copied verbatim from that shard,
    compressed chunks and all (HDF5 object copy, no codec work), for derived
    shards that change only some fields; ``arrays`` then holds the others.
    """
    import h5py

    path = Path(path)
    copied = {}
    if copy_from is not None:
        source, names = copy_from
        copied = read_shard(source, [f for f in names if f not in IMAGE_FIELDS])  # small; for checking
        with _open(source) as src:
            for f in names:
                if f in IMAGE_FIELDS:
                    copied[f] = np.broadcast_to(np.zeros((), src[f].dtype), src[f].shape)  # shape/dtype only
    n, h, w = check_arrays({**arrays, **copied})
    tmp = partial_path(path)
    try:
        with h5py.File(tmp, "w", track_order=True) as f, ThreadPoolExecutor(max_workers=2) as pool:
            if copy_from is not None:
                with h5py.File(copy_from[0], "r") as src:
                    for field in copy_from[1]:
                        src.copy(src[field], f, name=field)
            for field, value in arrays.items():
                dtype = {**FIELDS, **OPTIONAL_FIELDS}[field][0]
                if dtype == "str":
                    f.create_dataset(field, data=np.asarray([str(v) for v in value], dtype=object),
                                     dtype=h5py.string_dtype(), track_times=False)
                    continue
                value = np.ascontiguousarray(value)
                if field in IMAGE_FIELDS and n > 0:
                    _write_image_field(f, field, value, pool)
                else:
                    f.create_dataset(field, data=value, track_times=False)
            for key, value in attrs.items():
                f.attrs[key] = value
            f.attrs["schema_version"] = SCHEMA_VERSION
            f.attrs["frames"] = n
            f.attrs["height"] = h
            f.attrs["width"] = w
        with open(tmp, "rb") as fh:
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise ShardError(f"could not write shard {path}: {exc.strerror or exc}") from None
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return path


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
    """A shard's file attributes as plain Python values (checks the schema version)."""
    try:
        with _open(path) as f:
            attrs = {k: (v.item() if hasattr(v, "item") else v) for k, v in f.attrs.items()}
    except H5_ERRORS as exc:
        if isinstance(exc, ShardError):
            raise
        raise ShardError(f"{path}: corrupt shard attributes ({type(exc).__name__}: {exc})") from None
    version = attrs.get("schema_version")
    if version is None:
        raise ShardError(f"{path}: not an spm shard (no schema_version attribute)")
    if int(version) > SCHEMA_VERSION:
        raise ShardError(f"{path}: schema version {version} is newer than this spm "
                         f"({SCHEMA_VERSION}); upgrade spm to read it")
    return attrs


def read_shard(path, fields=None, frames=slice(None)) -> dict:
    """Read ``fields`` (default: all present) of a shard, for ``frames`` (a slice
    or sorted index array). String fields come back as (n,) object arrays of str."""
    read_attrs(path)
    with _open(path) as f:
        try:
            names = list(f.keys()) if fields is None else list(fields)
        except H5_ERRORS as exc:
            raise ShardError(f"{path}: corrupt shard index ({type(exc).__name__}: {exc})") from None
        out = {}
        for name in names:
            try:
                if name not in f:
                    raise ShardError(f"{path}: shard has no field {name!r}")
                ds = f[name]
                if h5_is_string(ds):
                    out[name] = np.asarray(ds.asstr()[frames], dtype=object)
                else:
                    out[name] = ds[frames]
            except ShardError:
                raise
            except (*H5_ERRORS, UnicodeDecodeError) as exc:
                raise ShardError(f"{path}: field {name!r} is corrupt ({type(exc).__name__}: {exc})") from None
    return out


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


def write_json_atomic(path, payload) -> None:
    with atomic_file(path) as tmp, open(tmp, "w") as fh:
        json.dump(payload, fh, indent=2, sort_keys=True)
        fh.write("\n")
        fh.flush()
        os.fsync(fh.fileno())


def write_manifest(folder, known: dict | None = None, extra: dict | None = None) -> dict:
    """(Re)write ``folder/manifest.json`` from the complete shards on disk.

    known: entries already computed this run, by file name (saves re-hashing);
    entries of the old manifest are reused when size still matches.
    extra: more top-level keys (e.g. merge's ``sources``); an old manifest's are kept.
    """
    folder = Path(folder)
    old, old_extra = {}, {}
    if (folder / MANIFEST).is_file():
        try:
            previous = read_manifest(folder)
            old = {e["file"]: e for e in previous["shards"]}
            old_extra = {k: v for k, v in previous.items() if k not in ("schema_version", "shards", "frames", "classes")}
        except ShardError:
            old = {}
    known = dict(known or {})
    entries = []
    for path in list_shards(folder):
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
    except (OSError, ValueError) as exc:
        raise ShardError(f"{path}: unreadable manifest ({exc})") from None
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

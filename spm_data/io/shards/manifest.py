"""A folder's shards and its ``manifest.json``, written last (atomically), read strictly."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from spm_data.errors import ShardError
from spm_data.io.files import PARTIAL_PREFIX, PARTIAL_SUFFIX, file_sha256, write_json_atomic
from spm_data.io.shards.reader import ShardReader
from spm_data.io.shards.schema import MANIFEST, MISSING, SCHEMA_VERSION, SHARD_SUFFIX

def no_shards(where, hint: str = "make some with `spm-data render` or `spm-data import`") -> ShardError:
    """The one error for a place with no shards in it (raise it)."""
    return ShardError(f"no shards (*.h5) in {where}; {hint}")


def list_shards(folder) -> list[Path]:
    """The complete shards directly in ``folder`` or, for a file, that file."""
    folder = Path(folder)
    if folder.is_file():
        return [folder]
    if not folder.is_dir():
        raise ShardError(f"no such folder or shard: {folder}")
    return sorted(p for p in folder.iterdir()
                  if p.suffix == SHARD_SUFFIX and not p.name.startswith(PARTIAL_PREFIX))


def manifest_entry(path, written=None) -> dict:
    """One manifest row for a complete shard: counts per class and a checksum.

    written: ``(attrs, class names)`` of a shard this process has just written
    (ShardWriter.written), so the shard is hashed but not opened and verified again."""
    path = Path(path)
    if written is None:
        with ShardReader(path) as reader:  # one open: attributes verified once
            written = reader.attrs, reader.read(["class_name"])["class_name"]
    attrs, names = written
    names = np.asarray(names, dtype=object)
    classes, counts = np.unique(names.astype(str), return_counts=True) if len(names) else ([], [])
    return {"file": path.name, "frames": int(attrs["frames"]), "bytes": path.stat().st_size,
            "sha256": file_sha256(path), "classes": {str(c): int(k) for c, k in zip(classes, counts)},
            "renderer": str(attrs.get("renderer", "")), "schema_version": int(attrs["schema_version"])}


def write_manifest(folder, known: dict | None = None, extra: dict | None = None, names=None) -> dict:
    """(Re)write ``folder/manifest.json``: the shards the old manifest listed and,
    of ``names`` (this run's shards), those complete on disk. Any other ``.h5``
    in the folder is not adopted (``names=None``: every complete shard on disk).

    known: entries already computed this run, by file name (saves re-hashing);
    entries of the old manifest are reused when size still matches.
    extra: more top-level keys (e.g. merge's ``sources``); an old manifest's are kept.
    """
    folder = Path(folder)
    old, old_extra = {}, {}
    if (folder / MANIFEST).exists():
        try:
            previous = read_manifest(folder)
            old = {e["file"]: e for e in previous["shards"] if isinstance(e, dict) and "file" in e}
            old_extra = {k: v for k, v in previous.items() if k not in ("schema_version", "shards", "frames",
                                                                        "classes")}
        except (ShardError, TypeError):
            old = {}
    known = dict(known or {})
    wanted = None if names is None else set(old) | set(names)
    entries = []
    for path in list_shards(folder):
        if wanted is not None and path.name not in wanted:
            continue
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
    except IsADirectoryError:
        raise ShardError(f"{path} is a folder, not a manifest; move it away and run the command again") from None
    except (OSError, ValueError) as exc:
        raise ShardError(f"{path}: unreadable manifest ({getattr(exc, 'strerror', None) or exc})") from None
    if not isinstance(payload, dict) or not isinstance(payload.get("shards"), list):
        raise ShardError(f"{path}: manifest has no 'shards' list")
    problem = _manifest_problem(payload)
    if problem:
        raise ShardError(f"{path}: {problem}; the manifest is damaged: run the command that wrote the folder "
                         "again, or delete it and pass --allow-partial")
    return payload


def _is_int(value) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and value >= 0


def _manifest_problem(payload: dict) -> str | None:
    """What makes a parsed manifest unusable (types a reader relies on), or None."""
    for i, entry in enumerate(payload["shards"]):
        if not isinstance(entry, dict) or not isinstance(entry.get("file"), str):
            return f"shards[{i}] is {json.dumps(entry)[:60]}, not an entry with a 'file' name"
        for key in ("frames", "bytes"):
            if key in entry and not _is_int(entry[key]):
                return f"shards[{i}] ({entry['file']}): '{key}' is {json.dumps(entry[key])[:40]}, not a count"
        if "classes" in entry and not (isinstance(entry["classes"], dict)
                                       and all(_is_int(v) for v in entry["classes"].values())):
            return f"shards[{i}] ({entry['file']}): 'classes' is not a table of frame counts"
    twice = listed_twice(payload["shards"])
    if twice:
        return twice
    missing = payload.get(MISSING, [])
    if not isinstance(missing, list) or not all(isinstance(m, str) for m in missing):
        return f"'{MISSING}' is {json.dumps(missing)[:60]}, not a list of shard names"
    if "frames" in payload and not _is_int(payload["frames"]):
        return f"'frames' is {json.dumps(payload['frames'])[:40]}, not a count"
    return None


def listed_twice(entries: list) -> str | None:
    """The one rule every reader of shards applies (read_manifest, merge): no shard is read
    twice. What is wrong with ``entries`` ([{"file", "sha256"?}, ...]): a name listed twice, or
    two shards of equal content (SHA-256), whose frames would be read twice (a test frame
    training too, an export writing it twice); None when each shard is there once."""
    names: dict = {}
    digests: dict = {}
    for entry in entries:
        name, digest = entry["file"], entry.get("sha256")
        if name in names:
            return f"{name} is listed twice"
        names[name] = True
        if isinstance(digest, str) and digest:
            if digest in digests:
                return (f"{digests[digest]} and {name} have the same content (SHA-256 {digest[:12]}…), so its "
                        "frames would be read twice")
            digests[digest] = name
    return None


def remove_partials(folder) -> list[Path]:
    """Delete ``.*.partial`` leftovers of killed runs in ``folder``; returns them."""
    folder = Path(folder)
    stale = [p for p in folder.glob(PARTIAL_PREFIX + "*" + PARTIAL_SUFFIX)] if folder.is_dir() else []
    for p in stale:
        p.unlink(missing_ok=True)
    return stale

"""Reading a shard folder the way it was written: by its manifest.

``manifest.json`` is written last, so it lists exactly the shards a finished
run made. A reader takes those, refuses a folder a live run is still writing
(its lock names the run), treats a listed shard that is missing or changed
size as an error, and ignores (with a warning) an ``.h5`` the manifest does not
list. ``allow_partial`` reads what is complete so far instead, warning about
each gap. Shards themselves verify as they are read (shards.py). No frame is read twice:
a shard whose bytes another holds, or a frame another shard holds, is refused, from what the
shards hold (io/shards/identity.py), whatever the manifest says.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from pathlib import Path

from spm_data.errors import ShardError, SpmWarning
from spm_data.io.locking import lock_owner
from spm_data.io.shards import MANIFEST, MISSING, SHARD_SUFFIX, list_shards, no_shards, read_manifest
from spm_data.io.shards.identity import read_twice


@dataclass(frozen=True)
class ShardFolder:
    """A folder's shards as its manifest lists them (a single shard file: itself)."""

    path: Path
    shards: tuple          # Path of every shard to read, in manifest order
    ignored: tuple = ()    # .h5 files on disk the manifest does not list
    manifest: dict | None = None


def _warn(message: str) -> None:
    warnings.warn(message, SpmWarning, stacklevel=3)


def open_folder(folder, *, allow_partial: bool = False) -> ShardFolder:
    """The shards of ``folder`` (or the one shard file ``folder``) to read.

    Raises ShardError when a live run holds the folder's lock, when there is no
    manifest, or when a listed shard is missing or changed size; with
    ``allow_partial`` those become warnings and the complete shards on disk are
    read. An unlisted ``.h5`` is always ignored with a warning.
    """
    folder = Path(folder)
    if folder.is_file() and folder.suffix == SHARD_SUFFIX:
        return ShardFolder(folder.parent, (folder,))
    if not folder.is_dir():
        raise ShardError(f"no such folder or shard: {folder}")
    owner = lock_owner(folder)
    if owner is not None:
        message = (f"{folder}/ is still being written by {owner}; wait for that run to finish, "
                   "or pass --allow-partial to read the shards complete so far")
        if not allow_partial:
            raise ShardError(message)
        _warn(message.split(";")[0] + "; reading the shards complete so far (--allow-partial)")
    on_disk = list_shards(folder)
    manifest = read_manifest(folder) if (folder / MANIFEST).exists() else None
    if not on_disk and not (manifest and manifest["shards"]):
        raise no_shards(folder)
    if manifest is None:
        if not allow_partial:
            raise ShardError(f"{folder}: no {MANIFEST}, so no finished run made these {len(on_disk)} shards "
                             "(a run writes it last, also when interrupted); run that command again to "
                             "finish it, or pass --allow-partial")
        _warn(f"{folder}: no {MANIFEST}; reading the {len(on_disk)} complete shards on disk (--allow-partial)")
        _check_read_once(folder, on_disk)
        return ShardFolder(folder, tuple(on_disk))
    _check_finished(folder, manifest, allow_partial)
    shards, problems = _listed_shards(folder, manifest)
    if problems and not allow_partial:
        raise ShardError(problems[0] + (f" (and {len(problems) - 1} more)" if len(problems) > 1 else "")
                         + "; run `spm-data validate` on it, or pass --allow-partial to skip such shards")
    for problem in problems:
        _warn(problem + "; skipped (--allow-partial)")
    _check_read_once(folder, shards)
    listed = {Path(e.get("file", "")).name for e in manifest["shards"] if isinstance(e, dict)}
    ignored = tuple(p for p in on_disk if p.name not in listed)
    if ignored:
        names = ", ".join(p.name for p in ignored[:3]) + (" ..." if len(ignored) > 3 else "")
        _warn(f"{folder}: ignoring {len(ignored)} shard(s) {MANIFEST} does not list ({names})")
    return ShardFolder(folder, tuple(shards), ignored, manifest)


def _check_read_once(folder: Path, shards) -> None:
    """No frame read twice, decided from the shards' bytes (io/shards/identity.py), never from the
    manifest's sha256: a copy under another name is refused, also with --allow-partial."""
    twice = read_twice(shards, name=lambda p: p.name)
    if twice:
        raise ShardError(f"{folder}: {twice}; remove the copy (or the {MANIFEST} entry that lists it)")


def _check_finished(folder: Path, manifest: dict, allow_partial: bool) -> None:
    """A manifest names the planned shards its run did not make (failed, or interrupted):
    such a folder is refused, or read with a warning under ``allow_partial``."""
    missing = manifest.get(MISSING) or []
    if not missing:
        return
    names = ", ".join(str(m) for m in missing[:3]) + (" ..." if len(missing) > 3 else "")
    message = (f"{folder}: the run that wrote it did not finish: {len(missing)} planned shard(s) are missing "
               f"({names})")
    if not allow_partial:
        raise ShardError(message + "; run the same command again to make them, or pass --allow-partial "
                         "to read the complete ones")
    _warn(message + "; reading the complete ones (--allow-partial)")


def _listed_shards(folder: Path, manifest: dict) -> tuple[list, list]:
    """The manifest's shards present with the listed size, and what is wrong with the rest."""
    shards, problems = [], []
    for entry in manifest["shards"]:
        name = entry.get("file") if isinstance(entry, dict) else None
        if not isinstance(name, str) or Path(name).name != name or not name.endswith(SHARD_SUFFIX):
            problems.append(f"{folder / MANIFEST}: a bad shard entry {entry!r}")
            continue
        path = folder / name
        if not path.is_file():
            problems.append(f"{folder}: {name} is listed in {MANIFEST} but missing")
        elif entry.get("bytes") is not None and path.stat().st_size != entry["bytes"]:
            problems.append(f"{path}: {path.stat().st_size} bytes on disk, {MANIFEST} says {entry['bytes']}; "
                            "it changed after the run wrote it")
        else:
            shards.append(path)
    return shards, problems


def find_folders(root) -> list[Path]:
    """Folders under ``root`` (itself included) that hold shards or a manifest;
    hidden folders (caches, partials) skipped. A shard file: itself."""
    root = Path(root)
    if root.is_file():
        return [root]
    if not root.is_dir():
        raise ShardError(f"no such folder: {root}")
    found = []
    for d in [root, *sorted(p for p in root.rglob("*") if p.is_dir())]:
        if any(part.startswith(".") for part in d.relative_to(root).parts):
            continue
        if (d / MANIFEST).exists() or any(p.suffix == SHARD_SUFFIX for p in d.iterdir() if p.is_file()):
            found.append(d)
    return found


def open_tree(root, *, allow_partial: bool = False) -> list[Path]:
    """Every shard to read under ``root``: each folder read by its manifest."""
    shards = [s for d in find_folders(root) for s in open_folder(d, allow_partial=allow_partial).shards]
    if not shards:
        raise no_shards(root)
    twice = read_twice(shards)   # across folders: a folder and its copy, or a merge of another
    if twice:
        raise ShardError(f"{root}: {twice}; keep one of them under {root}")
    return shards

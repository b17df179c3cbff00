"""`spm-data validate DIR`: every shard against the schema, and the manifest against the files.

Returns problems as (shard or "manifest.json", message); none means valid. A
flipped byte is caught by the checksum (and, inside compressed chunks, by the
decoder), a truncated file by HDF5, a newer schema by its version, a manifest
that disagrees with the files by comparing the two, a mesh a frame names that the folder's
store (meshes/) lacks or holds damaged by the store's own check, and what a writer that was
killed left (partial files, its lock) named as such.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from spm_data.errors import MeshError, ShardError
from spm_data.core.mesh_store import STORE, load_mesh
from spm_data.core.poses import STORED_ROTATION_TOLERANCE, pose_to_label, rotation_error
from spm_data.io.files import PARTIAL_PREFIX, PARTIAL_SUFFIX, file_sha256
from spm_data.io.locking import LOCK_NAME, lock_owner
from spm_data.io.shards.identity import read_twice
from spm_data.io.shards import (FIELDS, MANIFEST, MAY_BE_ABSENT, MISSING, OPTIONAL_FIELDS, check_arrays, list_shards,
                                 no_shards, read_attrs, read_manifest, read_shard, shard_layout)


def _angle_difference(a, b):
    return np.abs((np.asarray(a) - np.asarray(b) + 180.0) % 360.0 - 180.0)


def validate_shard(path) -> list[str]:
    """Problems of one shard (empty list: valid)."""
    try:
        attrs = read_attrs(path)
        data = read_shard(path)
    except ShardError as exc:
        return [str(exc).replace(f"{path}: ", "")]
    problems = []
    missing = [f for f in FIELDS if f not in data and f not in MAY_BE_ABSENT]
    if missing:
        return [f"missing fields {', '.join(missing)}"]
    unknown = [f for f in data if f not in FIELDS and f not in OPTIONAL_FIELDS]
    if unknown:
        problems.append(f"unknown fields {', '.join(unknown)}")
    try:
        n, h, w = check_arrays({k: v for k, v in data.items() if k not in unknown})
    except ShardError as exc:
        return problems + [str(exc)]
    if int(attrs.get("frames", -1)) != n:
        problems.append(f"attribute frames = {attrs.get('frames')} but the datasets hold {n} frames")
    for name in ("R", "t", "K", "pose"):
        bad = ~np.isfinite(data[name].reshape(n, -1)).all(axis=1)
        if bad.any():
            problems.append(f"non-finite {name} in frames {np.flatnonzero(bad)[:10].tolist()}")
    R = data["R"]
    if n and np.isfinite(R).all():
        bad = rotation_error(R) > STORED_ROTATION_TOLERANCE
        if bad.any():
            problems.append(f"R is not a rotation in frames {np.flatnonzero(bad)[:10].tolist()}")
        elif np.isfinite(data["t"]).all() and np.isfinite(data["pose"]).all():
            label = pose_to_label(R, data["t"]).reshape(n, 6)
            off = (_angle_difference(label[:, :3], data["pose"][:, :3]).max(axis=1) > 1e-6) | \
                  (np.abs(label[:, 3:] - data["pose"][:, 3:]).max(axis=1) > 1e-9)
            if off.any():
                problems.append(f"pose disagrees with R, t in frames {np.flatnonzero(off)[:10].tolist()}")
    infinite = np.isinf(data["distance"])  # NaN: not known (an import may leave it so), inf: never
    if infinite.any():
        problems.append(f"infinite distance in frames {np.flatnonzero(infinite)[:10].tolist()}")
    empty = ~data["mask"].reshape(n, -1).any(axis=1)
    if empty.any():
        problems.append(f"empty mask in {int(empty.sum())} frames (first: {np.flatnonzero(empty)[:10].tolist()})")
    if np.any((data["mask"] > 1)):
        problems.append("mask holds values other than 0 and 1")
    if "depth" in data and ((data["depth"] < 0).any() or not np.isfinite(data["depth"]).all()):
        problems.append("depth has negative or non-finite values")
    return problems


def _phase(progress, label: str, total: int) -> None:
    """Start a step of ``progress`` (spm_data.jobs.progress.Progress, or any callable with a
    settable ``total``) counting ``total`` shards."""
    if progress is not None:
        if hasattr(progress, "phase"):
            progress.phase(label, total, "shard")
        else:
            progress.total = total


def validate_folder(folder, progress=None) -> list[tuple[str, str]]:
    """(where, problem) for every shard in ``folder`` and its manifest. progress: a callable
    taking shard deltas (two steps: every shard read whole, then the checksums)."""
    folder = Path(folder)
    shards = list_shards(folder)
    if not shards:
        raise no_shards(folder, "nothing to validate")
    _phase(progress, "validate", len(shards))
    problems = []
    for p in shards:
        problems += [(p.name, msg) for msg in validate_shard(p)]
        if progress is not None:
            progress(1)
    problems += _store_problems(shards)
    left = leftovers(folder) if folder.is_dir() else []
    try:
        manifest = read_manifest(folder) if folder.is_dir() else None
    except ShardError as exc:
        said = str(exc).replace(f"{folder}/", "").replace(f"{folder}: ", "").removeprefix(f"{MANIFEST}: ")
        if left and not (folder / MANIFEST).exists():
            said += (f": the run that wrote this folder was stopped before it finished (killed?) and left "
                     f"{', '.join(left)}; run that command again to finish it (it resumes, and removes them)")
        return problems + [(MANIFEST, said)]
    problems += [(name, "left by a run that was stopped before it finished (killed?); the next run into this "
                        "folder removes it") for name in left]
    if manifest is None:
        return problems
    for name in manifest.get(MISSING) or []:
        problems.append((MANIFEST, f"the run that wrote it did not make {name} (failed or interrupted); "
                                   "run it again to finish"))
    listed = {e.get("file"): e for e in manifest["shards"]}
    on_disk = {p.name: p for p in shards}
    for name in sorted(set(listed) - set(on_disk)):
        problems.append((MANIFEST, f"lists {name}, which is not in the folder"))
    for name in sorted(set(on_disk) - set(listed)):
        problems.append((MANIFEST, f"does not list {name}"))
    twice = read_twice([on_disk[n] for n in listed if n in on_disk], name=lambda p: p.name)   # from the bytes
    if twice:
        problems.append((MANIFEST, f"{twice}; remove the copy (or the entry that lists it)"))
    _phase(progress, "validate checksums", len(set(listed) & set(on_disk)))
    for name in sorted(set(listed) & set(on_disk)):
        if progress is not None:
            progress(1)
        entry, path = listed[name], on_disk[name]
        try:
            size = path.stat().st_size
            digest = file_sha256(path) if entry.get("bytes") == size else None
        except OSError as exc:  # unreadable, a symlink loop: said, and the other shards still checked
            problems.append((name, f"cannot be read ({exc.strerror or exc}); fix it or replace it"))
            continue
        if entry.get("bytes") != size:
            problems.append((name, f"size {size} bytes, manifest says {entry.get('bytes')} (truncated or replaced?)"))
        elif entry.get("sha256") != digest:
            problems.append((name, "checksum differs from the manifest (a changed or flipped byte)"))
        try:
            frames = int(read_attrs(path)["frames"])
        except (ShardError, KeyError, ValueError):
            continue
        if entry.get("frames") != frames:
            problems.append((name, f"manifest says {entry.get('frames')} frames, the shard has {frames}"))
    total = sum(int(e.get("frames", 0)) for e in manifest["shards"])
    if manifest.get("frames") != total:
        problems.append((MANIFEST, f"total frames {manifest.get('frames')} is not the sum of its shards ({total})"))
    return problems


def _store_problems(shards) -> list[tuple[str, str]]:
    """(meshes/DIGEST, problem) for each mesh a frame names that its folder's store lacks or holds damaged."""
    named: set = set()
    for path in shards:
        try:
            layout, attrs = shard_layout(path), read_attrs(path)
            if "mesh" in layout:
                named |= set(map(str, read_shard(path, ["mesh"])["mesh"]))
            named |= set(json.loads(attrs.get("distractor_mesh_digests") or "[]"))
        except (ShardError, ValueError):
            continue   # the shard's own problem is reported above
    problems = []
    for digest in sorted(named - {""}):
        try:
            load_mesh(shards[0].parent, digest)
        except MeshError as exc:
            problems.append((f"{STORE}/{digest[:12]}…", str(exc).split(": ", 1)[-1]))
    return problems


def leftovers(folder: Path) -> list[str]:
    """What a killed writer leaves in ``folder``: its partial files (``.NAME.partial``, also in the
    mesh store) and a lock whose process is gone; a live run's lock is said as such."""
    left = sorted(p.name for p in folder.glob(PARTIAL_PREFIX + "*" + PARTIAL_SUFFIX))
    left += sorted(f"{STORE}/{p.name}" for p in (folder / STORE).glob(PARTIAL_PREFIX + "*" + PARTIAL_SUFFIX))
    if (folder / LOCK_NAME).exists():
        owner = lock_owner(folder)
        left.append(f"{LOCK_NAME} (its run is gone)" if owner is None else f"{LOCK_NAME} (held by {owner}: "
                                                                            "still running?)")
    return left


def validation_report(folder, problems) -> str:
    if not problems:
        return f"{folder}: all shards valid; manifest agrees with the files"
    lines = [f"{folder}: {len(problems)} problem{'' if len(problems) == 1 else 's'}"]
    lines += [f"  {where}: {msg}" for where, msg in problems]
    return "\n".join(lines)

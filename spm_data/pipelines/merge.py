"""`spm-data merge A B ... --out C`: shard folders of any sources into one, rebalanced
into full shards (one run of shards per image size), every frame exactly once."""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from spm_data.core.shard_meshes import FrameMeshes
from spm_data.core.specs import class_name_problem
from spm_data.errors import SpmError
from spm_data.io.folders import open_folder
from spm_data.io.outputs import check_out_name
from spm_data.io.shards.identity import read_twice
from spm_data.jobs.shard_runs import RunSummary, run_shard_jobs
from spm_data.io.shards import (FIELDS, MAY_BE_ABSENT, OPTIONAL_FIELDS, SIZED_FIELDS, manifest_entry, read_attrs,
                                read_shard, shard_digest, shard_layout, verify_shard, write_shard)


PLACED = ("distractor_mesh", "distractor_R", "distractor_t", "distractor_size")   # per-frame lists of 3-D distractors


@dataclass(frozen=True)
class MergeJob:
    name: str
    plan_key: str
    out_dir: str
    frames_from: tuple = field(repr=False)   # ((shard path, (frame indices...)), ...)
    renames: tuple = ()                      # ((old class, new class), ...)
    optional: tuple = ()                     # optional fields every source shard has

    @property
    def frames(self) -> int:
        return sum(len(idx) for _, idx in self.frames_from)


def parse_renames(spec: str | None) -> dict[str, str]:
    """``old=new,old2=new2`` -> dict."""
    if not spec:
        return {}
    out = {}
    for part in spec.split(","):
        if "=" not in part or not part.split("=", 1)[0].strip() or not part.split("=", 1)[1].strip():
            raise SpmError(f"--rename: expected OLD=NEW[,OLD=NEW...], got {part!r}")
        old, new = (x.strip() for x in part.split("=", 1))
        problem = class_name_problem(new)
        if problem:  # the rule render applies: a merged class must be one a render could have made
            raise SpmError(f"--rename {old}={new}: {problem}")
        out[old] = new
    return out


def plan_merge(inputs, out_dir, *, sources=None, renames=None, frames_per_shard=256,
               allow_partial=False) -> list[MergeJob]:
    if not inputs:
        raise SpmError("give at least one folder to merge")
    out_dir = check_out_name(out_dir)
    shards = []
    for folder in inputs:
        folder = Path(folder)
        if out_dir.exists() and folder.resolve() == out_dir.resolve():
            raise SpmError(f"--out {out_dir} is one of the inputs; merge into a new folder")
        shards += open_folder(folder, allow_partial=allow_partial).shards
    seen: dict = {}
    for path in shards:
        first = seen.setdefault(path.resolve(), path)
        if first is not path:
            raise SpmError(f"{path.name} is in the inputs twice ({first.parent} and {path.parent}); give each "
                           "folder once")
    info = {p: _shard_info(p) for p in shards}  # attrs, sources, fields and checksum, read once each
    twice = read_twice(shards)   # the rule every reader applies (io/folders.py): no frame is read twice
    if twice:
        raise SpmError(f"merge: {twice}; give each folder once (a copy of a folder, or a merge of it, holds "
                       "the same frames)")
    renames = renames or {}
    groups: dict[tuple, list] = {}   # (H, W) -> [(shard, frames)]
    for path in shards:
        i = info[path]
        keep = np.arange(i["frames"])
        if sources:
            keep = keep[np.isin(i["source"], list(sources))]
        if len(keep):
            groups.setdefault((i["height"], i["width"]), []).append((path, keep))
    if not groups:
        raise SpmError(f"no frames left after --sources {','.join(sources or [])}")
    jobs = []
    for (h, w), items in sorted(groups.items()):
        flat = [(str(p), int(i)) for p, idx in items for i in idx]
        tag = f"{w}x{h}"
        for k, start in enumerate(range(0, len(flat), frames_per_shard)):
            part = flat[start:start + frames_per_shard]
            by_shard: dict[str, list] = {}
            for p, i in part:
                by_shard.setdefault(p, []).append(i)
            frames_from = tuple((p, tuple(ix)) for p, ix in by_shard.items())
            optional = tuple(f for f in OPTIONAL_FIELDS
                             if all(f in info[Path(p)]["fields"] for p, _ in frames_from)
                             # 3-D distractors: kept when any source has them (frames without: none, -1)
                             or (f in PLACED and any(set(PLACED) <= info[Path(p)]["fields"] for p, _ in frames_from))
                             # occluded frames keep what is hidden (frames without: all of the mask seen)
                             or (f == "visible_mask" and any(f in info[Path(p)]["fields"] for p, _ in frames_from)))
            stamp = [(p, info[Path(p)]["sha256"]) for p, _ in frames_from]
            key = hashlib.sha256(json.dumps([stamp, frames_from, sorted(renames.items()), optional]).encode())
            jobs.append(MergeJob(f"merged-{tag}-{k:05d}.h5", key.hexdigest(), str(out_dir), frames_from,
                                 tuple(sorted(renames.items())), optional))
    return jobs


def _shard_info(path) -> dict:
    attrs = verify_shard(path)  # every checksum, before anything is written
    fields = set(shard_layout(path))
    return {"schema_version": int(attrs["schema_version"]), "frames": int(attrs["frames"]),
            "height": int(attrs["height"]), "width": int(attrs["width"]), "fields": fields,
            "source": read_shard(path, ["source"])["source"].astype(str), "sha256": shard_digest(path),
            # the pool's names, and the seed that made its procedural meshes
            "distractor_meshes": (attrs.get("distractor_meshes", ""), int(attrs.get("seed", 0)))}


def merge_shard(job: MergeJob, report=lambda n: None) -> dict:
    parts, pools = [], []
    fields = list(FIELDS) + [f for f in job.optional if f != "mesh"]
    for path, frames in job.frames_from:
        layout = shard_layout(path)
        part = read_shard(path, [f for f in fields if f in layout or f in MAY_BE_ABSENT]   # no depth: zeros
                          + (["mesh"] if "mesh" in layout else []), frames=np.asarray(frames))
        for f in set(fields) - set(part):   # a field this source lacks: nothing hidden, no distractors
            dtype, shape = OPTIONAL_FIELDS[f]
            part[f] = part["mask"].copy() if f == "visible_mask" else \
                np.zeros((len(frames), 0) + tuple(d for d in shape[1:]), dtype=dtype)
        attrs, meshes = read_attrs(path), FrameMeshes(Path(path).parent)
        part["mesh"] = np.asarray(meshes.targets(attrs, part), dtype=object)   # older shards: rebuilt
        pools.append(meshes.pool(attrs) if "distractor_mesh" in job.optional and "distractor_mesh" in layout else [])
        meshes.carry(list(part["mesh"]) + pools[-1], job.out_dir)   # the store travels with its frames
        parts.append(part)
        report(len(frames))
    fields.append("mesh")
    arrays = {}
    for f in fields:
        values = [p[f] for p in parts]
        if f in SIZED_FIELDS:  # per-frame lists (rectangles, distractors, lights): pad to the longest
            width = max(v.shape[1] for v in values)
            fill = -1 if f == "distractor_mesh" else 0
            values = [np.pad(v, [(0, 0), (0, width - v.shape[1])] + [(0, 0)] * (v.ndim - 2), constant_values=fill)
                      for v in values]
        arrays[f] = np.concatenate(values)
    renames = dict(job.renames)
    arrays["class_name"] = np.asarray([renames.get(c, c) for c in arrays["class_name"]], dtype=object)
    pool = {}
    if "distractor_mesh" in job.optional:
        arrays["distractor_mesh"], pool = _one_pool(job, parts, pools)
    attrs = {"plan_key": job.plan_key, "renderer": "merged", "seed": 0, "source": "merged", **pool,
             "merged_from": json.dumps([[Path(p).parent.name + "/" + Path(p).name, len(ix)]
                                        for p, ix in job.frames_from])}
    target = write_shard(Path(job.out_dir) / job.name, arrays, attrs)
    return {"entry": manifest_entry(target)}


def _one_pool(job: MergeJob, parts: list, pools: list) -> tuple[np.ndarray, dict]:
    """The merged shard's distractor_mesh (indices into one pool: every source pool's meshes, each
    once, by digest) and its pool attributes."""
    names, digests, index = [], [], {}
    remapped = []
    for (path, _), part, pool in zip(job.frames_from, parts, pools):
        source_names = json.loads(read_attrs(path).get("distractor_meshes") or "[]")
        lookup = np.full(len(source_names) + 1, -1, np.int64)   # the last entry: -1 stays -1
        for k, name in enumerate(source_names):
            digest = pool[k] if k < len(pool) else ""
            key = digest or name
            if key not in index:
                index[key] = len(names)
                names.append(name)
                digests.append(digest)
            lookup[k] = index[key]
        remapped.append(lookup[part["distractor_mesh"]])
    width = max(r.shape[1] for r in remapped)
    merged = np.concatenate([np.pad(r, [(0, 0), (0, width - r.shape[1])], constant_values=-1) for r in remapped])
    return merged, {"distractor_meshes": json.dumps(names), "distractor_mesh_digests": json.dumps(digests)}


def _warn_shared_names(out_dir) -> None:
    """One warning when two different meshes carry one class and instance name: they become two
    objects (bop/ids.py), which a user reading names alone would not expect."""
    import warnings

    from spm_data.errors import SpmWarning

    seen: dict[tuple, set] = {}
    for path in open_folder(out_dir).shards:
        d = read_shard(path, ["class_name", "instance_name", "mesh"])
        for cls, name, digest in zip(d["class_name"], d["instance_name"], d["mesh"]):
            seen.setdefault((str(cls), str(name)), set()).add(str(digest))   # "": a frame without a mesh
    shared = sorted(f"{c}/{n} ({len(d)} {'meshes' if '' not in d else 'objects: meshes or none'})"
                    for (c, n), d in seen.items() if len(d) > 1)
    if shared:
        warnings.warn(SpmWarning(f"{len(shared)} name(s) stand for different meshes: {', '.join(shared[:5])}"
                                 f"{' …' if len(shared) > 5 else ''}; each mesh is its own object "
                                 "(export bop gives each its own obj_id); rename with --rename to tell them apart"))


def merge_folders(inputs, out_dir, *, sources=None, renames=None, frames_per_shard=256,
                  progress=None, executor=None, allow_partial=False) -> RunSummary:
    """Merge shard folders into ``out_dir``; the manifest records every source folder."""
    jobs = plan_merge(inputs, out_dir, sources=sources, renames=renames, frames_per_shard=frames_per_shard,
                      allow_partial=allow_partial)
    read = {Path(p) for j in jobs for p, _ in j.frames_from}  # the shards each folder's manifest listed
    record = {"sources": [{"folder": str(Path(f)), "shards": sum(p.parent == Path(f) for p in read)}
                          for f in inputs],
              "filters": {"sources": list(sources or []), "classes": renames or {}}}
    summary = run_shard_jobs(merge_shard, jobs, out_dir, executor=executor, progress=progress, verb="merged",
                             manifest_extra=record)
    if not (summary.failed or summary.interrupted):
        _warn_shared_names(out_dir)
    return summary

"""`spm-data occlude`: write occluded copies of a shard folder (the input is only read).

One job per (input shard, copy). Frame ``i`` of copy ``k`` of shard ``S`` draws
its target and rectangles from ``default_rng([seed, crc32(S), i, k])``, so the
output does not depend on workers or order, and a seed gives identical bytes.
"""

from __future__ import annotations

import hashlib
import json
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from spm_data.errors import Option, ShardError, SpmError
from spm_data.io.folders import open_folder
from spm_data.io.outputs import check_out_name
from spm_data.core.occlusion import black_out, check_range, occlude_mask
from spm_data.jobs.plan_diff import first_difference
from spm_data.jobs.shard_runs import RunSummary, run_shard_jobs
from spm_data.core.mesh_store import carry_meshes
from spm_data.io.shards import (ShardReader, ShardWriter, hash_ahead, manifest_entry, read_attrs, reuse_verification,
                                verification)
from spm_data.io.shards.chunks import runs

DERIVED_FIELDS = ("visible_mask", "source_shard", "source_frame")
# What a copy is made with, by key (the command line names them by flag: spm_cli/support.py);
# the shard's attribute of each, in that order.
OPTIONS = tuple(map(Option, ("min", "max", "rects", "seed", "copy")))
OPTION_ATTRS = ("occlusion_min", "occlusion_max", "occlusion_rects", "occlusion_seed", "occlusion_copy")
IMAGES = ("rgb", "visible_mask")  # what occlude writes anew; in this order (the same bytes as before)


@dataclass(frozen=True)
class OccludeJob:
    source: str          # input shard path
    name: str            # output shard name
    copy: int
    low: float
    high: float
    rects: int
    seed: int
    plan_key: str
    out_dir: str
    frames: int
    verified: tuple | None = None  # the parent's check of the source (seal.py): not hashed again in a worker

    def options(self) -> dict:
        """The options this copy is made with, by key (OPTIONS)."""
        return dict(zip(OPTIONS, (self.low, self.high, self.rects, self.seed, self.copy)))

    def plan_difference(self, attrs: dict) -> tuple | str | None:
        """(key, old, new): the option (an OPTIONS key: ``max``...) that the shard with ``attrs`` was
        made with otherwise, or a phrase for another input (shard_runs' refusal); None if none is found."""
        found = first_difference(dict(zip(OPTIONS, (attrs[a] for a in OPTION_ATTRS))), self.options())
        was, now = str(attrs.get("source_plan_key", "")), str(read_attrs(self.source).get("plan_key", ""))
        if found is None and was != now:
            return (f"was made from another version of its input {Path(self.source).name} (made with plan "
                    f"{was[:12] or 'unknown'}, which is now {now[:12] or 'unknown'})")
        return found


def occlusion_report(summary: RunSummary) -> str:
    unreachable = sum(r["unreachable"] for r in summary.results.values())
    return summary.report([f"  {unreachable} frames could not reach their target (object too small or thin); "
                           "they keep the closest coverage found"])


def check_inputs(in_dir, out_dir, allow_partial=False) -> dict:
    """Every input shard (as the folder's manifest lists them), checked before anything is
    written: {path: its verified attributes}."""
    in_dir, out_dir = Path(in_dir), check_out_name(out_dir)
    if not in_dir.is_dir():
        raise ShardError(f"input folder not found: {in_dir}")
    if out_dir.exists() and out_dir.resolve() == in_dir.resolve():
        raise ShardError(f"--out {out_dir} is the input folder; occlusion never modifies its input, "
                         "give another --out")
    shards, paths = {}, open_folder(in_dir, allow_partial=allow_partial).shards
    hash_ahead(paths)  # on two threads; each open below finds its file's check done
    for path in paths:
        with ShardReader(path) as reader:  # every checksum, before anything is written; one open
            attrs = shards[path] = reader.attrs
            try:
                has_object = _any_mask(reader, int(attrs["frames"]))
            except ShardError as exc:
                raise ShardError(f"{path}: cannot occlude a shard without masks ({exc})") from None
            data, layout = reader.read(["occlusion_rects"]), reader.layout()
        if int(attrs["frames"]) and not has_object:
            raise ShardError(f"{path}: every mask is empty, so there is no object to occlude")
        if data["occlusion_rects"].any():
            raise ShardError(f"{path}: already occluded; occlude the unoccluded shards instead")
        if "visible_mask" in layout:
            raise ShardError(f"{path}: already occluded (it has a visible_mask, e.g. from [distractors]); "
                             "occlude shards rendered without distractors")
    return shards


def _any_mask(reader: ShardReader, frames: int) -> bool:
    """Whether any frame's mask has a pixel: decoded a run at a time up to the first that has
    one (usually the first run; the bytes were verified whole when the shard was opened)."""
    for run in runs(frames):
        if reader.read(["mask"], frames=slice(run.start, run.stop))["mask"].any():
            return True
    if not frames:
        reader.read(["mask"], frames=slice(0, 0))  # a shard without the field says so
    return False


MAX_RECTS = 64  # rectangles per frame: more only slows placement (each takes a share of the target)
MAX_SEED = 2**63 - 1


def check_options(low, high, copies, rects, seed) -> None:
    """SpmError for options out of range, before any shard is read, naming each by key (Option)."""
    check_range(low, high)
    if copies < 1 or rects < 1:
        raise SpmError(Option("copies"), " and ", Option("rects"), f" must be >= 1, got {copies} and {rects}")
    if rects > MAX_RECTS:
        raise SpmError(Option("rects"), f" {rects}: at most {MAX_RECTS} rectangles per frame")
    if not 0 <= seed <= MAX_SEED:
        raise SpmError(Option("seed"), f" {seed}: expected an integer in [0, {MAX_SEED}]")


def plan_occlusion(shards: dict, out_dir, low, high, copies=1, rects=1, seed=0) -> list[OccludeJob]:
    """One job per (shard, copy); shards: {path: verified attributes} (check_inputs); the options
    as occlude_dataset, the entry, checked them (check_options)."""
    jobs = []
    for path, attrs in shards.items():
        stamp = f"{path.name}:{attrs.get('plan_key', '')}:{path.stat().st_size}"
        for k in range(copies):
            key = hashlib.sha256(json.dumps([stamp, low, high, rects, seed, k]).encode()).hexdigest()
            name = f"{path.stem}-occ{k}.h5" if copies > 1 else path.name
            jobs.append(OccludeJob(str(path), name, k, float(low), float(high), int(rects), int(seed), key,
                                   str(out_dir), int(attrs["frames"]), verification(path)))
    return jobs


def occlude_shard(job: OccludeJob, report=lambda n: None) -> dict:
    """Occlude every frame of one input shard; write the output shard atomically. The input
    is opened once (its every byte verified); the frames are placed a run at a time while
    the writer's threads compress the runs before."""
    reuse_verification(job.source, job.verified)
    with ShardReader(job.source) as reader:
        data, attrs, layout = reader.read(["mask", "class_name"]), reader.attrs, reader.layout()
        data["rgb"] = reader.read_runs("rgb")  # decoded on the reader's threads while frames are placed
        n, (h, w) = int(attrs["frames"]), data["mask"].shape[1:]
        labels = dict(occlusion_rects=np.zeros((n, job.rects, 4), np.int32),
                      occlusion_fraction=np.zeros(n, np.float32),
                      source_shard=np.asarray([Path(job.source).name] * n, dtype=object),
                      source_frame=np.arange(n, dtype=np.int64))
        unchanged = [name for name in layout if name not in (*IMAGES, *labels)]
        out_attrs = {k: v for k, v in attrs.items() if k not in ("schema_version", "frames", "height", "width")}
        out_attrs.update(plan_key=job.plan_key, occlusion_seed=job.seed, occlusion_min=job.low,
                         occlusion_max=job.high, occlusion_rects=job.rects, occlusion_copy=job.copy,
                         occlusion_source=Path(job.source).name, source_plan_key=attrs.get("plan_key", ""))
        if "mesh" in layout:   # the meshes the frames name travel with them, before the shard lands
            carry_meshes(set(map(str, reader.read(["mesh"])["mesh"])), [Path(job.source).parent], job.out_dir)
        with ShardWriter(Path(job.out_dir) / job.name, frames=n, height=h, width=w, images=IMAGES) as writer:
            images = {"rgb": np.empty(layout["rgb"][0], np.uint8), "visible_mask": np.zeros((n, h, w), np.uint8)}
            reached = _place(job, data, images, labels, writer, report)
            writer.write_images(0, images)
            # Depth, mask, poses...: copied chunk for chunk, no decompressing and recompressing.
            target = writer.finish(labels, out_attrs, copy_from=(reader, unchanged))
            entry = manifest_entry(target, writer.written)
    return {"entry": entry, "unreachable": int((~reached).sum())}


def _place(job: OccludeJob, data: dict, images: dict, labels: dict, writer, report) -> np.ndarray:
    """Draw and apply every frame's rectangles into ``images`` and ``labels`` (in place), handing
    each run of frames to the writer's threads as it is done; returns which frames reached their
    target. Frame i draws from default_rng([seed, crc32(source name), i, copy])."""
    reached = np.zeros(len(labels["source_frame"]), bool)
    stem = zlib.crc32(Path(job.source).name.encode())
    for run, rgb in data["rgb"]:  # rgb(): the run's frames, decoded
        for i in run:
            rng = np.random.default_rng([job.seed, stem, i, job.copy])
            target = float(rng.uniform(job.low, job.high)) if job.high > job.low else job.low
            occ = occlude_mask(data["mask"][i], target, rng, rects=job.rects, bounds=(job.low, job.high))
            labels["occlusion_rects"][i], labels["occlusion_fraction"][i], reached[i] = (occ.rects, occ.fraction,
                                                                                         occ.reached)
        # apply_occlusion, in place on the output arrays: the run copied once, then its rectangles blacked out
        images["rgb"][run.start:run.stop] = rgb()
        np.greater(data["mask"][run.start:run.stop], 0, out=images["visible_mask"][run.start:run.stop])
        for i in run:
            black_out(images["rgb"][i], images["visible_mask"][i], rects=labels["occlusion_rects"][i])
        writer.prepare(run.start, {name: frames[run.start:run.stop] for name, frames in images.items()})
        report(len(run))
    return reached


def occlude_dataset(in_dir, out_dir, *, low=0.0, high=0.6, copies=1, rects=1, seed=0,
                    progress=None, executor=None, allow_partial=False) -> RunSummary:
    """Occlude every shard of ``in_dir`` into ``out_dir`` (resuming), then write its manifest.
    Everything is checked before anything is written, the options first and once (check_options);
    ``allow_partial``: see folders.open_folder."""
    check_options(low, high, copies, rects, seed)
    shards = check_inputs(in_dir, out_dir, allow_partial)
    jobs = plan_occlusion(shards, out_dir, low, high, copies, rects, seed)
    # Light jobs: this process occludes too while the other workers start (their imports cost
    # about as much as a shard's work).
    return run_shard_jobs(occlude_shard, jobs, out_dir, executor=executor, progress=progress, verb="occluded",
                          parent_works=True)

"""`spm-data occlude`: write occluded copies of a shard folder (the input is only read).

One job per (input shard, copy). Frame ``i`` of copy ``k`` of shard ``S`` draws
its target and rectangles from ``default_rng([seed, crc32(S), i, k])``, so the
output does not depend on workers or order, and a seed gives identical bytes.
"""

from __future__ import annotations

import hashlib
import json
import time
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import h5py
import numpy as np

from spm_data.errors import ShardError, SpmError
from spm_data.executor import run_jobs
from spm_data.locking import OutputLock
from spm_data.occlusion import apply_occlusion, check_range, occlude_mask
from spm_data.render_jobs import prepare_out_dir
from spm_data.shards import (list_shards, manifest_entry, partial_path, read_attrs, read_shard, remove_partials,
                             write_manifest, write_shard)

DERIVED_FIELDS = ("visible_mask", "source_shard", "source_frame")


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


@dataclass
class OccludeSummary:
    out_dir: Path
    planned: int = 0
    written: list = field(default_factory=list)
    skipped: list = field(default_factory=list)
    failed: list = field(default_factory=list)
    frames: int = 0
    unreachable: int = 0     # frames whose target could not be met (closest kept)
    fractions: list = field(default_factory=list)
    seconds: float = 0.0
    interrupted: bool = False

    def report(self) -> str:
        lines = [f"occluded {self.frames} frames into {len(self.written)} shards in {self.seconds:.1f} s; "
                 f"{len(self.skipped)} already complete; {len(self.failed)} failed -> {self.out_dir}/",
                 f"  {self.unreachable} frames could not reach their target (object too small or thin); "
                 "they keep the closest coverage found"]
        lines += [f"  failed {name}: {err}" for name, err in self.failed]
        if self.interrupted:
            lines.append(f"interrupted: run the same command again to resume into {self.out_dir}/")
        return "\n".join(lines)


def check_inputs(in_dir, out_dir) -> list[Path]:
    """Every input shard, checked before anything is written."""
    in_dir, out_dir = Path(in_dir), Path(out_dir)
    if not in_dir.is_dir():
        raise ShardError(f"input folder not found: {in_dir}")
    if out_dir.exists() and out_dir.resolve() == in_dir.resolve():
        raise ShardError(f"--out {out_dir} is the input folder; occlusion never modifies its input, "
                         "give another --out")
    shards = list_shards(in_dir)
    if not shards:
        raise ShardError(f"no shards (*.h5) in {in_dir}; render some first (spm-data render --out {in_dir})")
    for path in shards:
        attrs = read_attrs(path)
        try:
            data = read_shard(path, ["mask", "occlusion_rects"])
        except ShardError as exc:
            raise ShardError(f"{path}: cannot occlude a shard without masks ({exc})") from None
        if int(attrs["frames"]) and not data["mask"].any():
            raise ShardError(f"{path}: every mask is empty, so there is no object to occlude")
        if data["occlusion_rects"].any():
            raise ShardError(f"{path}: already occluded; occlude the unoccluded shards instead")
    return shards


def plan_occlusion(shards, out_dir, low, high, copies=1, rects=1, seed=0) -> list[OccludeJob]:
    check_range(low, high)
    if copies < 1 or rects < 1:
        raise SpmError(f"--copies and --rects must be >= 1, got {copies} and {rects}")
    jobs = []
    for path in shards:
        attrs = read_attrs(path)
        stamp = f"{path.name}:{attrs.get('plan_key', '')}:{path.stat().st_size}"
        for k in range(copies):
            key = hashlib.sha256(json.dumps([stamp, low, high, rects, seed, k]).encode()).hexdigest()
            name = f"{path.stem}-occ{k}.h5" if copies > 1 else path.name
            jobs.append(OccludeJob(str(path), name, k, float(low), float(high), int(rects), int(seed), key,
                                   str(out_dir), int(attrs["frames"])))
    return jobs


def occlude_shard(job: OccludeJob, report=lambda n: None) -> dict:
    """Occlude every frame of one input shard; write the output shard atomically."""
    data = read_shard(job.source, ["rgb", "mask"])
    attrs = read_attrs(job.source)
    n = int(attrs["frames"])
    h, w = data["mask"].shape[1:]
    rgb = data["rgb"].copy()
    visible = np.zeros((n, h, w), np.uint8)
    rects = np.zeros((n, job.rects, 4), np.int32)
    fractions = np.zeros(n, np.float32)
    reached = np.zeros(n, bool)
    stem = zlib.crc32(Path(job.source).name.encode())
    for i in range(n):
        rng = np.random.default_rng([job.seed, stem, i, job.copy])
        target = float(rng.uniform(job.low, job.high)) if job.high > job.low else job.low
        occ = occlude_mask(data["mask"][i], target, rng, rects=job.rects, bounds=(job.low, job.high))
        rgb[i], visible[i] = apply_occlusion(data["rgb"][i], data["mask"][i], occ.rects)
        rects[i], fractions[i], reached[i] = occ.rects, occ.fraction, occ.reached
        report(1)
    changed = dict(rgb=rgb, visible_mask=visible, occlusion_rects=rects, occlusion_fraction=fractions,
                   source_shard=np.asarray([Path(job.source).name] * n, dtype=object),
                   source_frame=np.arange(n, dtype=np.int64))
    with h5py.File(job.source, "r") as f:
        unchanged = [name for name in f.keys() if name not in changed]
    out_attrs = {k: v for k, v in attrs.items() if k not in ("schema_version", "frames", "height", "width")}
    out_attrs.update(plan_key=job.plan_key, occlusion_seed=job.seed, occlusion_min=job.low,
                     occlusion_max=job.high, occlusion_rects=job.rects, occlusion_copy=job.copy,
                     occlusion_source=Path(job.source).name, source_plan_key=attrs.get("plan_key", ""))
    # Depth, mask, poses...: copied chunk for chunk, no decompressing and recompressing.
    target = write_shard(Path(job.out_dir) / job.name, changed, out_attrs, copy_from=(job.source, unchanged))
    return {"entry": manifest_entry(target), "unreachable": int((~reached).sum()),
            "fractions": fractions.tolist()}


def _discard_partial(job: OccludeJob) -> None:
    partial_path(Path(job.out_dir) / job.name).unlink(missing_ok=True)


def occlude_dataset(in_dir, out_dir, *, low=0.0, high=0.6, copies=1, rects=1, seed=0, workers=1,
                    progress=None) -> OccludeSummary:
    """Occlude every shard of ``in_dir`` into ``out_dir`` (resuming), then write its manifest."""
    shards = check_inputs(in_dir, out_dir)
    jobs = plan_occlusion(shards, out_dir, low, high, copies, rects, seed)  # validates before writing
    out = prepare_out_dir(out_dir)
    started = time.perf_counter()
    summary = OccludeSummary(out_dir=out, planned=len(jobs))
    with OutputLock(out):
        remove_partials(out)
        todo = []
        for job in jobs:
            target = out / job.name
            if target.exists():
                if read_attrs(target).get("plan_key") != job.plan_key:
                    raise ShardError(f"{target} was made from other input or options; "
                                     f"occlude into a new --out folder or delete {out}")
                summary.skipped.append(job.name)
            else:
                todo.append(job)
        if progress is not None:
            progress.total = sum(j.frames for j in todo)
        entries = {}

        def on_outcome(o):
            if o.error:
                summary.failed.append((o.job.name, o.error))
                return
            summary.written.append(o.job.name)
            summary.frames += o.job.frames
            summary.unreachable += o.result["unreachable"]
            summary.fractions += o.result["fractions"]
            entries[o.job.name] = o.result["entry"]

        try:
            run_jobs(occlude_shard, todo, workers=0 if workers <= 1 else workers, on_outcome=on_outcome,
                     on_progress=progress, on_worker_death=_discard_partial)
        except KeyboardInterrupt:
            summary.interrupted = True
        finally:
            remove_partials(out)
            write_manifest(out, known=entries)
    summary.seconds = time.perf_counter() - started
    return summary

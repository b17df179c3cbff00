"""A resumable run of shard jobs into one output folder: the mechanism render, occlude
(and the importers) share.

A job is anything with ``name`` (the shard file), ``plan_key`` (what it was
made from: inputs, options, seed), ``frames`` and ``out_dir``; its function
writes the shard atomically and returns ``{"entry": manifest entry, ...}``.
The run holds the folder's lock, clears leftovers of killed runs, skips shards
already complete for the same plan, refuses ones made for another plan, runs
the rest (worker processes may crash; see executor.py), and writes the manifest
last, also when interrupted. A job may also offer ``plan_difference(attrs)``, so
that a refusal names what differs (plan_diff.py).
"""

from __future__ import annotations

import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path

from spm_data.core.mesh_store import STORE
from spm_data.errors import ShardError
from spm_data.jobs.executor import LocalExecutor
from spm_data.io.locking import GUARD_NAME, OutputLock
from spm_data.jobs.plan_diff import refusal
from spm_data.io.files import partial_path
from spm_data.io.outputs import check_out_name
from spm_data.io.shards import MANIFEST, MISSING, remove_partials, verify_shard, write_manifest


@dataclass
class RunSummary:
    out_dir: Path
    verb: str = "wrote"           # "rendered", "occluded", ...
    planned: int = 0
    done: list = field(default_factory=list)      # shard names written by this run
    skipped: list = field(default_factory=list)   # already complete
    redone: list = field(default_factory=list)    # (shard name, why): on disk but failed verification
    failed: list = field(default_factory=list)    # (shard name, error)
    results: dict = field(default_factory=dict)   # shard name -> what its job returned
    frames: int = 0
    seconds: float = 0.0
    interrupted: bool = False
    complete: int = 0             # planned shards complete on disk when the run ended

    def report(self, details=()) -> str:
        """What happened, in a few lines for a person; ``details``: extra lines. Interrupted: one
        line (and the shards that failed), from what is on disk when the run ended: workers may
        have finished shards the run was not told of."""
        lines = [] if self.interrupted else [
            f"{self.verb} {_count(len(self.done), 'shard')} ({_count(self.frames, 'frame')}) in {self.seconds:.1f} s; "
            f"{len(self.skipped)} already complete; {len(self.failed)} failed -> {self.out_dir}/", *details]
        lines += [f"  redone {name}: {why}" for name, why in self.redone]
        lines += [f"  failed {name}: {err}" for name, err in self.failed]
        if self.interrupted:
            lines.append(self._interrupted_line())
        return "\n".join(lines)

    def _interrupted_line(self) -> str:
        out = Path(self.out_dir)
        if not out.is_dir():
            return "interrupted before any shard was complete; nothing was written"
        listed = " (listed in manifest.json)" if (out / MANIFEST).is_file() else ""
        verb = "is" if self.planned == 1 else "are"
        return (f"interrupted: {self.complete} of {_count(self.planned, 'shard')} {verb} complete in "
                f"{self.out_dir}/{listed}; run the same command again to resume")


def _count(n: int, noun: str) -> str:
    """"1 shard", "2 shards"."""
    return f"{n:,} {noun}" + ("" if n == 1 else "s")


def prepare_out_dir(out_dir) -> Path:
    out = check_out_name(out_dir)
    if out.exists() and not out.is_dir():
        raise ShardError(f"output path {out} is a file; give a folder")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ShardError(f"cannot create output folder {out}: {exc.strerror}") from None
    if (out / MANIFEST).is_dir():
        raise ShardError(f"{out / MANIFEST} is a folder, not a manifest; move it away and run the command again")
    return out


def _pending(jobs, summary: RunSummary) -> list:
    """Jobs whose shard is not already complete and intact. A shard that fails
    verification (corrupt, truncated) is redone; an intact one made from
    another plan is refused."""
    todo = []
    for job in jobs:
        target = Path(job.out_dir) / job.name
        if not target.exists():
            todo.append(job)
            continue
        try:
            attrs = verify_shard(target)
        except ShardError as exc:
            summary.redone.append((job.name, str(exc).removeprefix(f"{target}: ")))
            todo.append(job)
            continue
        if attrs.get("plan_key") != job.plan_key:
            raise ShardError(*refusal(job, target, attrs))   # naming what differs, where the job can tell
        summary.skipped.append(job.name)
    return todo


def _discard_partial(job) -> None:
    partial_path(Path(job.out_dir) / job.name).unlink(missing_ok=True)


def run_shard_jobs(fn, jobs, out_dir, *, executor=None, in_process=True, progress=None, verb="wrote",
                   manifest_extra=None, parent_works=False) -> RunSummary:
    """Run ``fn(job, report)`` for the jobs whose shard is missing, then write the manifest.

    executor: where the jobs run (spm_data.jobs.make_executor: its workers,
    recycling and retries); default: this process. in_process: whether a local
    executor with one worker may run the jobs in this process (not for Blender);
    parent_works: with several local workers, this process is one of them (light jobs,
    for which a new process's start-up is a large share; executor.run_jobs).
    progress: a callable taking frame deltas with a ``total`` attribute (a tqdm
    bar), or None. Jobs write their shard themselves; only their small results
    come back here, and the manifest is written here, last.
    """
    if executor is None:
        executor = LocalExecutor(workers=1, retries=1)
    created = not Path(out_dir).exists()
    out = prepare_out_dir(out_dir)
    started = time.perf_counter()
    summary = RunSummary(out_dir=out, verb=verb, planned=len(jobs))
    try:
        return _run_locked(fn, jobs, out, summary, started, executor, (in_process, parent_works), progress,
                           manifest_extra)
    except OSError as exc:  # the folder itself: read-only, full, gone (shards' own errors are ShardErrors)
        raise ShardError(f"cannot write to {out}/: {exc.strerror or exc}") from None
    finally:
        if created:
            remove_if_empty(out)


def remove_if_empty(folder: Path) -> None:
    """Remove a folder this run created when nothing is left in it but the lock's guard file and
    the mesh store its jobs filled before their shards failed (no shard, no manifest, no other
    run's lock): a failed run (a full disk) leaves nothing, OUT/meshes/*.npz included."""
    try:
        if not {p.name for p in folder.iterdir()} <= {GUARD_NAME, STORE}:
            return
        if (folder / STORE).is_dir():
            shutil.rmtree(folder / STORE)
        (folder / GUARD_NAME).unlink(missing_ok=True)
        folder.rmdir()
    except OSError:
        pass  # someone else is using it: leave it


def _run_locked(fn, jobs, out, summary, started, executor, where, progress, manifest_extra) -> RunSummary:
    in_process, parent_works = where
    with OutputLock(out):
        remove_partials(out)
        todo = _pending(jobs, summary)
        if progress is not None:
            progress.total = sum(j.frames for j in todo)
        entries = {}

        def on_outcome(o):
            if o.error:
                summary.failed.append((o.job.name, o.error))
                return
            summary.done.append(o.job.name)
            summary.frames += o.result.get("frames", o.job.frames)  # importers may skip unreadable frames
            summary.results[o.job.name] = o.result
            if o.result.get("entry") is not None:
                entries[o.job.name] = o.result["entry"]

        try:
            executor.run(fn, todo, in_process=in_process, on_outcome=on_outcome, on_progress=progress,
                         on_worker_death=_discard_partial, **({"parent_works": True} if parent_works else {}))
        except KeyboardInterrupt:
            summary.interrupted = True
        finally:
            remove_partials(out)
            # No shard at all (say, every job failed on a broken mesh): no manifest either.
            # Planned shards that failed or were never made are named in the manifest, so readers
            # know the folder is incomplete (io/folders.open_folder refuses it without --allow-partial).
            # A job that ran and had nothing to write (an import whose every frame was skipped) is
            # not missing: running it again makes nothing either.
            empty = {name for name, result in summary.results.items() if result.get("entry", True) is None}
            missing = [job.name for job in jobs if not (out / job.name).exists() and job.name not in empty]
            if (out / MANIFEST).exists() or any((out / job.name).exists() for job in jobs):
                write_manifest(out, known=entries, extra={**(manifest_extra or {}), MISSING: missing},
                               names=[job.name for job in jobs])
            summary.complete = sum((out / job.name).exists() for job in jobs)
    summary.seconds = time.perf_counter() - started
    return summary

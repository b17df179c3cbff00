"""Render specs into shard folders: plan shards, render the missing ones, write the manifest.

The unit of work is one shard: ``frames_per_shard`` consecutive frames of a
class's frame list (every instance's camera path, instance after instance).
A shard that exists is complete (shards.ShardWriter is atomic) and carries
the ``plan_key`` it was made for, so a re-run skips it, and a re-run with a
different spec or options refuses to mix its frames in.
"""

from __future__ import annotations

import hashlib
import json
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass, field, replace
from functools import lru_cache, partial
from pathlib import Path

import numpy as np

from spm_data.version import __version__
from spm_data.errors import RenderError, SpecError
from spm_data.core.instances import instance_count, load_instance, mesh_attrs, mesh_record
from spm_data.core.paths import camera_path
from spm_data.core.poses import pose_to_label
from spm_data.render import RENDERERS, make_renderer
from spm_data.pipelines.render_frames import FrameMaker, FramePipeline, pipeline_threads
from spm_data.core.distractors import pool_names
from spm_data.core.mesh_store import save_mesh
from spm_data.core.shard_meshes import store_pool
from spm_data.jobs.executor import LocalExecutor
from spm_data.jobs.plan_diff import first_difference, flatten
from spm_data.jobs.shard_runs import RunSummary, run_shard_jobs
from spm_data.io.outputs import check_out_name
from spm_data.io.shards import SCHEMA_VERSION, ShardWriter, manifest_entry
from spm_data.core.specs import RenderSpec, all_spec_paths, find_spec, load_spec, shard_spec, validate_spec


@dataclass(frozen=True, init=False)
class ShardJob:
    """One shard's frames: either given (``instances``, ``path_indices``) or
    ``frame_range = (first, stop, n_path)``, frames ``first .. stop - 1`` of the
    class's frame list (frame ``g`` is instance ``g // n_path`` at path index
    ``g % n_path``), turned into arrays only when asked, so a plan of many
    shards holds no per-frame arrays."""

    spec: RenderSpec
    name: str
    shard_index: int
    plan_key: str = ""
    out_dir: str = ""
    frame_range: tuple = field(default=(), repr=False)  # (frames_from, frames_to, n_path), or ()
    _given: tuple = field(default=(), repr=False)       # (instances, path_indices), or ()
    limit: int | None = None                            # the run's --limit (part of the plan)

    def __init__(self, spec, name, shard_index, instances=None, path_indices=None, plan_key="", out_dir="",
                 frame_range=(), limit=None):
        given = ()
        if instances is not None or path_indices is not None:
            given = (np.asarray(instances, dtype=np.int64), np.asarray(path_indices, dtype=np.int64))
            if given[0].shape != given[1].shape or given[0].ndim != 1 or frame_range:
                raise ValueError("ShardJob: give instances and path_indices of one length, or frame_range")
        elif not frame_range:
            raise ValueError("ShardJob: give instances and path_indices, or frame_range")
        for key, value in (("spec", spec), ("name", name), ("shard_index", shard_index), ("plan_key", plan_key),
                           ("out_dir", out_dir), ("frame_range", tuple(int(v) for v in frame_range)),
                           ("_given", given), ("limit", None if limit is None else int(limit))):
            object.__setattr__(self, key, value)

    @property
    def frames(self) -> int:
        return int(len(self._given[0])) if self._given else self.frame_range[1] - self.frame_range[0]

    def frame_ids(self) -> tuple[np.ndarray, np.ndarray]:
        """(instances, path_indices): (n,) int64 each, the instance ids and camera path indices."""
        if self._given:
            return self._given
        first, stop, n_path = self.frame_range
        return np.divmod(np.arange(first, stop, dtype=np.int64), n_path)

    def plan_difference(self, attrs: dict) -> tuple | None:
        """(key, old, new): the first spec key, seed, renderer or --limit that the shard with
        ``attrs`` was made with otherwise (shard_runs' refusal); None if none is found."""
        old = shard_spec(attrs, "the shard's spec", self.spec.base_dir)
        if attrs.get("renderer") in RENDERERS:   # --renderer changes the run's spec, not its text
            old = old.replace(render=replace(old.render, renderer=str(attrs["renderer"])))
        limit = int(attrs["frame_limit"]) or None if "frame_limit" in attrs else self.limit  # older: not kept
        if old.fingerprint() == self.spec.fingerprint():   # the same pixels: only the plan's options differ
            return first_difference({"--limit": limit}, {"--limit": self.limit})
        return first_difference(plan_of(old, limit), plan_of(self.spec, self.limit))

    @property
    def instances(self) -> np.ndarray:
        """(n,) int64 instance ids."""
        return self.frame_ids()[0]

    @property
    def path_indices(self) -> np.ndarray:
        """(n,) int64 indices into the camera path."""
        return self.frame_ids()[1]


# --------------------------------------------------------------------------- planning

def plan_of(spec: RenderSpec, limit: int | None) -> dict:
    """What a render plan is made from, flat: ``{"seed": 0, "camera.azimuth": [...], ..., "--limit": N}``."""
    tree = asdict(spec)
    for key in ("text", "base_dir", "class_name"):
        tree.pop(key)
    tree["mesh"].pop("symmetries")   # metadata, not pixels (RenderSpec.fingerprint)
    return {**flatten(tree), "--limit": limit}


def effective_spec(spec: RenderSpec, renderer: str | None = None, seed: int | None = None) -> RenderSpec:
    """``spec`` with command-line overrides applied."""
    if renderer is not None:
        spec = spec.replace(render=replace(spec.render, renderer=renderer))
        try:
            validate_spec(spec)  # what the spec asks may be beyond this renderer (Workbench: no normals)
        except SpecError as exc:
            raise SpecError(f"{spec.class_name} with --renderer {renderer}: {exc}") from None
    if seed is not None:
        spec = spec.replace(seed=int(seed))
        try:
            validate_spec(spec)
        except SpecError as exc:
            raise SpecError(f"{spec.class_name} with --seed {seed}: {exc}") from None
    return spec


def load_run_specs(classes=(), all_classes=False, spec_files=(), specs_dir=None, renderer=None, seed=None):
    """The specs a render run names: ``--class`` names, ``--all``, explicit files."""
    paths = [find_spec(c, specs_dir) for c in classes] + [Path(p) for p in spec_files]
    if all_classes:
        paths += all_spec_paths(specs_dir)
    if not paths:
        raise SpecError("nothing to render: give --class NAME, --all or --spec FILE")
    unique = list(dict.fromkeys(p.resolve() for p in paths))
    return [effective_spec(load_spec(p), renderer=renderer, seed=seed) for p in unique]


MAX_PLAN_FRAMES = 2 ** 40  # a frame list longer than this is a mistake in the spec, not a plan


def limit_picks(total: int, limit: int) -> np.ndarray:
    """The ``limit`` frame numbers (sorted, int64) of a ``total``-frame list that
    ``--limit`` renders, evenly spread (linspace builds ``limit`` values, never ``total``)."""
    if limit >= total:
        return np.arange(total, dtype=np.int64)
    return np.unique(np.round(np.linspace(0, total - 1, limit)).astype(np.int64))


def plan_shards(spec: RenderSpec, out_dir, limit: int | None = None) -> list[ShardJob]:
    """Split the class's frames into shard jobs. ``limit``: at most that many
    frames, evenly spread over all instances and views (a quick look).

    Memory is bounded by the jobs, not the frame list: without a limit a job is
    a range of frame numbers, with one only the picked frames are computed."""
    n_path = camera_path(spec.camera, spec.seed).size
    n_inst = instance_count(spec)
    total = n_path * n_inst
    if total > MAX_PLAN_FRAMES:
        raise SpecError(f"{spec.class_name}: {n_inst:,} instances x {n_path:,} camera views = {total:,} frames, "
                        f"more than 2**40 ({MAX_PLAN_FRAMES:,}); use coarser camera steps or fewer instances")
    if limit is not None and limit < 1:
        raise SpecError(f"--limit must be >= 1, got {limit}")
    key = hashlib.sha256(json.dumps({"spec": spec.fingerprint(), "limit": limit,
                                     "schema": SCHEMA_VERSION}).encode()).hexdigest()
    per = spec.render.frames_per_shard
    common = {"spec": spec, "plan_key": key, "out_dir": str(out_dir), "limit": limit}
    if limit is None or limit >= total:
        return [ShardJob(name=f"{spec.class_name}-{i:05d}.h5", shard_index=i,
                         frame_range=(s, min(s + per, total), n_path), **common)
                for i, s in enumerate(range(0, total, per))]
    pick = limit_picks(total, limit)
    instances, path_idx = np.divmod(pick, n_path)
    return [ShardJob(name=f"{spec.class_name}-{i:05d}.h5", shard_index=i,
                     instances=instances[s:s + per], path_indices=path_idx[s:s + per], **common)
            for i, s in enumerate(range(0, len(pick), per))]


# --------------------------------------------------------------------------- one shard

@lru_cache(maxsize=2)
def _renderer_for(spec: RenderSpec):
    return make_renderer(spec)


# A render worker is replaced after this many shards, so a leak in a renderer (Blender's
# grows over long runs) cannot grow without bound; the CLI's --recycle-after default.
RECYCLE_AFTER = 16
BLOCK_BYTES = 64 << 20  # raw image bytes a worker holds while writing a shard (at least one frame)


def block_frames(height: int, width: int, bytes_per_pixel: int = 8) -> int:
    """Frames per block of a shard being written: as many as fit BLOCK_BYTES of
    image fields (rgb + depth + mask: 8 bytes a pixel), at least one. A function
    of the spec only, so a spec's shards are the same bytes on every machine; a
    shard that fits one block is byte for byte what ``shards.write_shard`` writes."""
    return max(1, BLOCK_BYTES // (height * width * bytes_per_pixel))


def render_shard(job: ShardJob, report=lambda n: None) -> dict:
    """Render ``job`` and write its shard atomically; returns its manifest entry and ``seconds``,
    where the time went (render, readback, composite, compress, write: each stage's busy time;
    they overlap). This thread only renders: compositing, compression and storing run on a
    FramePipeline's threads, which store the chunks in the serial path's order (the same bytes),
    a block of frames at a time (block_frames), so a worker's memory stays about one block
    whatever the shard's length."""
    spec = job.spec
    renderer = _renderer_for(spec)
    maker = FrameMaker(spec, renderer)
    path = camera_path(spec.camera, spec.seed)
    instances, path_indices = job.frame_ids()
    points = path.at(path_indices)
    R, t = points.poses()
    n, h, w = job.frames, spec.image.height, spec.image.width
    per = max(1, min(n, block_frames(h, w, maker.bytes_per_pixel())))
    threads, readback = pipeline_threads(), renderer.readback_seconds
    with ShardWriter(Path(job.out_dir) / job.name, frames=n, height=h, width=w, images=maker.image_fields) as writer, \
            ThreadPoolExecutor(max_workers=1) as mesh_store:
        with FramePipeline(writer, per, threads, ahead=min(per, 4 * threads)) as pipeline:
            names, records, digests = _render_frames(job, maker, pipeline, (instances, path_indices, R, t),
                                                     mesh_store, report)
            frame_labels = pipeline.close()
        digests = {inst: saved.result() for inst, saved in digests.items()}  # stored before the shard naming them
        per_frame = {f: np.stack([fl[f] for fl in frame_labels]) for f in (frame_labels[0] if frame_labels else {})}
        labels = {
            "K": per_frame.pop("K", np.zeros((0, 3, 3))), "R": R, "t": t, "pose": pose_to_label(R, t).reshape(n, 6),
            "azimuth": points.azimuth, "elevation": points.elevation, "roll": points.roll,
            "distance": points.distance, "look_at": np.broadcast_to(path.look_at, (n, 3)).copy(),
            "path_index": path_indices.astype(np.int64), "instance_id": instances.astype(np.int64),
            "instance_name": [names[int(i)] for i in instances], "class_name": [spec.class_name] * n,
            "source": ["synthetic"] * n, "label_measured": np.ones((n, 6), bool),
            "mesh": [digests[int(i)] for i in instances],
            "occlusion_fraction": np.zeros(n, np.float32), "occlusion_rects": np.zeros((n, 1, 4), np.int32),
            **per_frame,
        }
        attrs = {"spec": spec.text, "spec_fingerprint": spec.fingerprint(), "plan_key": job.plan_key,
                 "frame_limit": job.limit or 0,  # 0: none; with the spec and seed, what the plan was
                 "seed": spec.seed, "class_name": spec.class_name, "shard_index": job.shard_index,
                 "renderer": renderer.name, "renderer_version": renderer.version(),
                 "renderer_settings": json.dumps(renderer.settings(), sort_keys=True),
                 "spm_version": __version__, "source": "synthetic", "object_size": spec.mesh.size,
                 **mesh_attrs(spec, records)}
        if maker.distractors:
            attrs["distractor_meshes"] = json.dumps(pool_names(spec))
            attrs["distractor_mesh_digests"] = json.dumps(store_pool(spec, job.out_dir, labels["distractor_mesh"]))
        started = time.perf_counter()
        target = writer.finish(labels, attrs)
        pipeline.seconds["write"] += time.perf_counter() - started
    readback = renderer.readback_seconds - readback
    seconds = {"render": maker.render_seconds - readback, "readback": readback, **pipeline.seconds}
    return {"entry": manifest_entry(target, writer.written), "seconds": seconds}


def _render_frames(job: ShardJob, maker: FrameMaker, pipeline: FramePipeline, frames: tuple, mesh_store,
                   report) -> tuple[dict, dict, dict]:
    """Render ``frames`` (instances, path indices, R, t) into ``pipeline``, a scene per instance;
    (names, records, digests) by instance, digests as futures of save_mesh on ``mesh_store``
    (a thread: the store's compression off the renderer's thread)."""
    spec, renderer = job.spec, maker.renderer
    instances, path_indices, R, t = frames
    current, names, records, digests = None, {}, {}, {}
    for i, (inst, pidx) in enumerate(zip(instances.tolist(), path_indices.tolist())):
        if inst != current:
            mesh = load_instance(spec, inst)
            renderer.set_mesh(mesh)
            current, names[inst] = inst, mesh.name
            records[inst] = mesh_record(spec, inst)
            digests[inst] = mesh_store.submit(save_mesh, job.out_dir, mesh)  # waited for before the shard
        rendered = maker.render(mesh, inst, pidx, R[i], t[i])  # new arrays every frame
        pipeline.put(partial(maker.finish, rendered, inst, pidx, R[i], t[i]))
        report(1)
    return names, records, digests


def render_dataset(specs: list[RenderSpec], out_dir, *, limit=None, progress=None, executor=None) -> RunSummary:
    """Render every spec into ``out_dir`` (resuming), then write manifest.json.

    executor: where shards are rendered (spm_data.jobs.make_executor: workers,
    recycling); default: one local worker, replaced every RECYCLE_AFTER shards.
    With one local worker pyrender renders in this process; Blender always
    renders in worker processes. progress: a callable taking frame deltas and a
    ``total`` attribute (e.g. a tqdm bar), or None.
    """
    check_out_name(out_dir)
    jobs = [job for spec in specs for job in plan_shards(spec, out_dir, limit)]
    names = [j.name for j in jobs]
    if len(set(names)) != len(names):
        raise SpecError("two specs share a class name; each class needs its own name")
    in_process = all(RENDERERS[j.spec.render.renderer].in_process for j in jobs)
    executor = executor or LocalExecutor(workers=1, retries=1, recycle_after=RECYCLE_AFTER)
    summary = run_shard_jobs(render_shard, jobs, out_dir, executor=executor, in_process=in_process,
                             progress=progress, verb="rendered")
    errors = {error for _, error in summary.failed}
    if len(errors) == 1 and not (summary.done or summary.skipped or summary.interrupted):
        # Nothing rendered, and every shard says the same (a GPU that is not there, a broken
        # mesh): that is the run's one error, not a summary of a folder that holds nothing.
        raise RenderError(errors.pop())
    return summary

"""Render specs into shard folders: plan shards, render the missing ones, write the manifest.

The unit of work is one shard: ``frames_per_shard`` consecutive frames of a
class's frame list (every instance's camera path, instance after instance).
A shard that exists is complete (shards.write_shard is atomic) and carries
the ``plan_key`` it was made for, so a re-run skips it, and a re-run with a
different spec or options refuses to mix its frames in.
"""

from __future__ import annotations

import glob
import hashlib
import json
import zlib
from dataclasses import dataclass, field, replace
from functools import lru_cache
from pathlib import Path

import numpy as np

from spm_data import __version__
from spm_data.backgrounds import background_image, composite
from spm_data.errors import SpecError
from spm_data.meshes import load_mesh_file, procedural_mesh
from spm_data.paths import camera_path
from spm_data.poses import pose_to_label
from spm_data.render import make_renderer, spec_intrinsics
from spm_data.shard_runs import RunSummary, run_shard_jobs
from spm_data.shards import SCHEMA_VERSION, manifest_entry, write_shard
from spm_data.specs import RenderSpec, all_spec_paths, find_spec, load_spec


@dataclass(frozen=True)
class ShardJob:
    spec: RenderSpec
    name: str
    shard_index: int
    instances: np.ndarray = field(repr=False)     # (n,) int64 instance ids
    path_indices: np.ndarray = field(repr=False)  # (n,) int64 indices into the camera path
    plan_key: str = ""
    out_dir: str = ""

    @property
    def frames(self) -> int:
        return int(len(self.instances))


# --------------------------------------------------------------------------- instances

def mesh_files(spec: RenderSpec) -> list[Path]:
    """The spec's mesh files (globs relative to the spec file), sorted, de-duplicated."""
    found: list[Path] = []
    for pattern in spec.mesh.files:
        full = pattern if Path(pattern).is_absolute() else str(Path(spec.base_dir) / pattern)
        matches = sorted(Path(p) for p in glob.glob(full, recursive=True))
        if not matches:
            raise SpecError(f"mesh.files: {pattern!r} matches no file (relative to {spec.base_dir})")
        found += [m for m in matches if m not in found]
    return found


def instance_count(spec: RenderSpec) -> int:
    return spec.mesh.instances if spec.mesh.source == "procedural" else len(mesh_files(spec))


@lru_cache(maxsize=8)
def load_instance(spec: RenderSpec, instance: int):
    """The TexturedMesh of ``instance`` (cached per process: frames arrive grouped by instance)."""
    m = spec.mesh
    if m.source == "procedural":
        return procedural_mesh(m.generator or spec.class_name, instance, seed=spec.seed, size=m.size)
    return load_mesh_file(mesh_files(spec)[instance], size=m.size, seed=spec.seed, instance=instance,
                          texture=m.texture)


def shard_mesh(attrs: dict, instance_id: int):
    """The TexturedMesh a synthetic shard's frame was rendered from (rebuilt from the
    spec and seed in the shard's attributes), or None for other sources."""
    if attrs.get("source") != "synthetic" or not attrs.get("spec"):
        return None
    from spm_data.specs import parse_spec

    spec = parse_spec(attrs["spec"]).replace(seed=int(attrs.get("seed", 0)))
    return load_instance(spec, instance_id)


# --------------------------------------------------------------------------- planning

def effective_spec(spec: RenderSpec, renderer: str | None = None, seed: int | None = None) -> RenderSpec:
    """``spec`` with command-line overrides applied."""
    if renderer is not None:
        spec = spec.replace(render=replace(spec.render, renderer=renderer))
    if seed is not None:
        spec = spec.replace(seed=int(seed))
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


def plan_shards(spec: RenderSpec, out_dir, limit: int | None = None) -> list[ShardJob]:
    """Split the class's frames into shard jobs. ``limit``: at most that many
    frames, evenly spread over all instances and views (a quick look)."""
    n_path = len(camera_path(spec.camera))
    n_inst = instance_count(spec)
    instances = np.repeat(np.arange(n_inst, dtype=np.int64), n_path)
    path_idx = np.tile(np.arange(n_path, dtype=np.int64), n_inst)
    if limit is not None:
        if limit < 1:
            raise SpecError(f"--limit must be >= 1, got {limit}")
        if limit < len(instances):
            pick = np.unique(np.round(np.linspace(0, len(instances) - 1, limit)).astype(np.int64))
            instances, path_idx = instances[pick], path_idx[pick]
    key = hashlib.sha256(json.dumps({"spec": spec.fingerprint(), "limit": limit,
                                     "schema": SCHEMA_VERSION}).encode()).hexdigest()
    per = spec.render.frames_per_shard
    return [ShardJob(spec=spec, name=f"{spec.class_name}-{i:05d}.h5", shard_index=i,
                     instances=instances[s:s + per], path_indices=path_idx[s:s + per],
                     plan_key=key, out_dir=str(out_dir))
            for i, s in enumerate(range(0, len(instances), per))]


# --------------------------------------------------------------------------- one shard

@lru_cache(maxsize=2)
def _renderer_for(spec: RenderSpec):
    return make_renderer(spec)


def frame_rng(spec: RenderSpec, instance: int, path_index: int) -> np.random.Generator:
    """Per-frame randomness (backgrounds): independent of shard layout and worker."""
    return np.random.default_rng([spec.seed, zlib.crc32(spec.class_name.encode()), instance, path_index, 1])


def render_shard(job: ShardJob, report=lambda n: None) -> dict:
    """Render ``job`` and write its shard atomically; returns its manifest entry."""
    spec = job.spec
    renderer = _renderer_for(spec)
    path = camera_path(spec.camera)
    R, t = path.poses(job.path_indices)
    n, h, w = job.frames, spec.image.height, spec.image.width
    arrays = {"rgb": np.zeros((n, h, w, 3), np.uint8), "depth": np.zeros((n, h, w), np.float32),
              "mask": np.zeros((n, h, w), np.uint8)}
    current = None
    for i, (inst, pidx) in enumerate(zip(job.instances, job.path_indices)):
        if inst != current:
            mesh = load_instance(spec, int(inst))
            renderer.set_mesh(mesh)
            current = inst
        out = renderer.render(R[i], t[i])
        if spec.background.kind == "black":
            arrays["rgb"][i] = out["rgb"]
        else:
            background = background_image(spec, frame_rng(spec, int(inst), int(pidx)))
            arrays["rgb"][i] = composite(out["rgb"], out["alpha"], background)
        arrays["depth"][i] = out["depth"]
        arrays["mask"][i] = out["mask"]
        report(1)
    names = {int(i): load_instance(spec, int(i)).name for i in np.unique(job.instances)}
    arrays.update({
        "K": np.broadcast_to(spec_intrinsics(spec), (n, 3, 3)).copy(), "R": R, "t": t,
        "pose": pose_to_label(R, t).reshape(n, 6),
        "azimuth": path.azimuth[job.path_indices], "elevation": path.elevation[job.path_indices],
        "roll": path.roll[job.path_indices], "distance": path.distance[job.path_indices],
        "look_at": np.broadcast_to(path.look_at, (n, 3)).copy(),
        "path_index": job.path_indices.astype(np.int64), "instance_id": job.instances.astype(np.int64),
        "instance_name": [names[int(i)] for i in job.instances], "class_name": [spec.class_name] * n,
        "source": ["synthetic"] * n, "label_measured": np.ones((n, 6), bool),
        "occlusion_fraction": np.zeros(n, np.float32), "occlusion_rects": np.zeros((n, 1, 4), np.int32),
    })
    attrs = {"spec": spec.text, "spec_fingerprint": spec.fingerprint(), "plan_key": job.plan_key,
             "seed": spec.seed, "class_name": spec.class_name, "shard_index": job.shard_index,
             "renderer": renderer.name, "renderer_version": renderer.version(),
             "renderer_settings": json.dumps(renderer.settings(), sort_keys=True),
             "spm_version": __version__, "source": "synthetic", "object_size": spec.mesh.size}
    target = write_shard(Path(job.out_dir) / job.name, arrays, attrs)
    return {"entry": manifest_entry(target)}


def render_dataset(specs: list[RenderSpec], out_dir, *, limit=None, workers=1, progress=None,
                   recycle_after=16, executor=None) -> RunSummary:
    """Render every spec into ``out_dir`` (resuming), then write manifest.json.

    workers: processes; 1 renders in this process with pyrender, and Blender
    always renders in worker processes. progress: a callable taking frame deltas
    and a ``total`` attribute (e.g. a tqdm bar), or None. recycle_after: a worker
    process is replaced after this many shards (0: never), so a leak in a
    renderer (Blender's grows over long runs) cannot grow without bound.
    executor: where shards are rendered (spm_data.executor.make_executor; it
    carries its own worker count and recycling); default: local processes.
    """
    jobs = [job for spec in specs for job in plan_shards(spec, out_dir, limit)]
    names = [j.name for j in jobs]
    if len(set(names)) != len(names):
        raise SpecError("two specs share a class name; each class needs its own name")
    in_process = all(j.spec.render.renderer == "pyrender" for j in jobs)
    return run_shard_jobs(render_shard, jobs, out_dir, workers=workers, in_process=in_process,
                          progress=progress, verb="rendered", recycle_after=recycle_after, executor=executor)

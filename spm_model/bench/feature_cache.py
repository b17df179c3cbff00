"""Features of every frame under a folder of shards, cached next to the shards.

Each shard's features live in ``<shard folder>/.spm-features/<shard stem>-<config
key>.npz`` (written to a temporary name and ``os.replace``-d, so a cache file
that exists is whole); where that folder cannot be created or written (read-only
shards), in the per-user cache ``$SPM_CACHE_DIR`` (else ``$XDG_CACHE_HOME/spm/features``,
default ``~/.cache/spm/features``) under a hash of the shard folder's absolute
path, with one warning. A cache file records the SHA-256 of the shard's content
it was made from, verified against the shard's bytes (spm_data.io.shards.shard_digest)
on every run: a shard changed since (rewritten, or a flipped byte with its mtime put back)
is extracted again, or refused when corrupt. A cache folder is created only to write a
file into it, and a run that fails removes the empty folders it made. Extraction runs
shard by shard on an executor (spm_data.jobs.make_executor), with per-frame progress.
"""

from __future__ import annotations

import contextlib
import errno
import hashlib
import json
import os
import socket
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from spm_data.errors import ShardError, SpmError, SpmWarning
from spm_data.jobs.executor import LocalExecutor
from spm_data.io.folders import open_tree
from spm_data.io.locking import pid_alive
from spm_data.io.files import PARTIAL_PREFIX, write_npz_atomic
from spm_data.io.outputs import nearest_existing, unwritable
from spm_data.io.shards import read_attrs, read_shard, shard_digest, shard_layout
from spm_model.base.frames import visible_field
from spm_model.base.model_files import model_seal
from spm_model.bench.extract import frames_features
from spm_model.spm.features import FeatureConfig

CACHE_DIR = ".spm-features"
LABEL_FIELDS = ("pose", "K", "label_measured", "class_name", "instance_name", "instance_id", "path_index",
                "occlusion_fraction", "source")
READ_BLOCK = 256  # frames read from a shard at a time (bounded memory for big shards)


def find_shards(folder, allow_partial: bool = False) -> list[Path]:
    """Every shard under ``folder``, each folder read by its manifest
    (spm_data.io.folders.open_tree; hidden folders skipped)."""
    return open_tree(folder, allow_partial=allow_partial)


def user_cache_root() -> Path:
    """The per-user feature cache: ``$SPM_CACHE_DIR``, else ``$XDG_CACHE_HOME/spm/features``
    (default ``~/.cache/spm/features``)."""
    if os.environ.get("SPM_CACHE_DIR"):
        return Path(os.environ["SPM_CACHE_DIR"]).expanduser()
    return Path(os.environ.get("XDG_CACHE_HOME") or Path("~/.cache").expanduser()) / "spm" / "features"


def user_cache_folder(shard_folder) -> Path:
    """The per-user cache of one shard folder: a subfolder named by a hash of its absolute path."""
    return user_cache_root() / hashlib.sha256(str(Path(shard_folder).resolve()).encode()).hexdigest()[:16]


def _unwritable(folder: Path) -> str | None:
    """None when ``folder`` is, or can be made as, a folder this process can write in, else
    why not. Creates nothing (a cache folder is made only to write into it)."""
    problem = unwritable(folder)
    if problem is None:
        return None
    return "a file is in the way" if problem[1] == "file" else os.strerror(errno.EACCES)


def cache_seal(identity: str, config_key: str, arrays: dict) -> str:
    """The SHA-256 a cache file carries over what it was computed from (its shard's SHA-256 and
    the feature configuration's key) and every array it holds (spm_model/base/model_files.py)."""
    return model_seal(json.dumps({"shard_sha256": identity, "features": config_key}), arrays)


_warned: list = [False]   # whether this process has said that a cache file was damaged


def read_cache(path: Path, digest: str, config: FeatureConfig) -> dict | None:
    """The arrays of the cache file ``path`` when it was made from the shard whose content has
    SHA-256 ``digest`` under ``config`` and holds exactly what it was sealed with; None when it
    is missing, of another shard or version (a rewritten shard: redone), or damaged, cut short
    or foreign (redone, the first such file in a process said in one ``warning:`` line)."""
    try:
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
    except FileNotFoundError:
        return None
    except Exception:  # noqa: BLE001 - any damage of the bytes (zip, .npy header, data) means: redo it
        arrays = {}
    identity, key, seal = (str(arrays.pop(k, "")) for k in ("identity", "features_key", "seal"))
    if seal and seal == cache_seal(identity, key, arrays):
        return arrays if (identity, key) == (digest, config.key()) else None
    if not _warned[0]:
        _warned[0] = True
        warnings.warn(f"feature cache {path} is damaged, cut short or not one this spm wrote; its features are "
                      "extracted again (any further ones in this process silently)", SpmWarning)
    return None


def _whole(path: Path, digest: str, config: FeatureConfig) -> bool:
    """Whether ``path`` is a sound cache file made from the shard with SHA-256 ``digest`` under ``config``."""
    return read_cache(path, digest, config) is not None


def cache_path(shard: Path, config: FeatureConfig, digest: str | None = None) -> Path:
    """Where ``shard``'s features are (or will be) cached: ``<shard folder>/.spm-features``, or,
    when that cannot be created or written, the per-user cache (user_cache_folder); a whole
    cache file already beside a read-only shard is used where it is. SpmError when neither
    place can be written. digest: the shard's verified SHA-256 (shard_digest), when known."""
    shard = Path(shard)
    name = f"{shard.stem}-{config.key()}.npz"
    beside = shard.parent / CACHE_DIR
    why = _unwritable(beside)
    if why is None or _whole(beside / name, digest or shard_digest(shard), config):
        return beside / name
    user = user_cache_folder(shard.parent)
    why_user = _unwritable(user)
    if why_user is None:
        return user / name
    raise SpmError(f"cannot cache features: neither {beside} ({why}) nor {user} ({why_user}) is writable; "
                   "set SPM_CACHE_DIR to a writable folder")


def memo_folder(shard, config: FeatureConfig) -> Path:
    """The folder of the per-image feature memo (spm_model/base/feature_memo.py): ``memo/``
    in the feature cache of ``shard``'s folder."""
    return cache_path(Path(shard), config).parent / "memo"


def cached(shard: Path, config: FeatureConfig) -> Path | None:
    """The shard's cache file when present and made from the shard as it is now (its bytes
    verified: a ShardError naming it when they fail)."""
    digest = shard_digest(shard)
    path = cache_path(shard, config, digest)
    return path if _whole(path, digest, config) else None


def walks_in_steps(attrs: dict) -> bool:
    """Whether a shard's consecutive path indices are neighbouring views (a rendered grid walk,
    or a turntable import); False for views a sampler drew at random (camera.sampler "sphere",
    "so3") and imports that say they are not a walk (attribute ``path_steps`` 0: captures)."""
    if not attrs.get("spec"):
        return bool(int(attrs.get("path_steps", 1)))
    from spm_data.core.specs import parse_spec

    return parse_spec(str(attrs["spec"])).camera.sampler == "grid"


def extract_shard(job, report=lambda n: None) -> str:
    """Compute and cache one shard's features; job = (shard path, FeatureConfig)."""
    shard, config = Path(job[0]), job[1]
    identity = shard_digest(shard)  # every byte checked: a missing, foreign or corrupt file is a ShardError
    attrs = read_attrs(shard)
    n = int(attrs["frames"])
    labels = read_shard(shard, LABEL_FIELDS)
    if np.any(labels["class_name"].astype(str) == ""):
        raise ShardError(f"{shard}: frames without a class_name; set one when importing")
    visible = visible_field(str(shard))  # features of what a camera sees: the visible mask where there is one
    parts = []
    # Path neighbours are looked up within a block of READ_BLOCK frames (a default shard is one block).
    for start in range(0, n, READ_BLOCK):
        block = slice(start, min(n, start + READ_BLOCK))
        images = read_shard(shard, ("rgb", visible, "depth"), frames=block)
        parts.append(frames_features(images["rgb"], images[visible], labels["instance_id"][block],
                                     labels["path_index"][block], config, report, K=labels["K"][block],
                                     path_steps=walks_in_steps(attrs), depth=images["depth"]))
        parts[-1]["width"] = np.full(block.stop - block.start, images["rgb"].shape[2], dtype=np.int64)
    features = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]} if parts else {}
    out = cache_path(shard, config, identity)
    # Host and pid in the temporary name: remove_stale_partials can tell a dead writer's leftovers.
    tmp = out.parent / f"{PARTIAL_PREFIX}{out.name}.{socket.gethostname()}.{os.getpid()}.partial"
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        arrays = {**features, **{k: (v.astype(str) if v.dtype == object else v) for k, v in labels.items()}}
        write_npz_atomic(out, tmp, identity=np.array(identity), features_key=np.array(config.key()),
                         seal=np.array(cache_seal(identity, config.key(), arrays)), **arrays)
    except OSError as exc:
        fix = "" if out.parent.name == CACHE_DIR else " or set SPM_CACHE_DIR to another folder"
        raise SpmError(f"could not write the feature cache {out}: {exc.strerror or exc}; "
                       f"free space there{fix}") from None
    return str(out)


def occluder_kind(shard) -> str:
    """What may hide the object in a shard's frames: "distractors" (3-D objects rendered in
    front of it), "rectangles" (spm-data occlude) or "none"."""
    layout = shard_layout(str(shard))
    return "distractors" if "distractor_R" in layout else "rectangles" if "visible_mask" in layout else "none"


def offgrid_table(train: "FeatureTable", test: "FeatureTable") -> "FeatureTable":
    """One table of a training folder's frames and a test folder's, with ``test`` (n,) bool
    and ``seen`` (n,) bool (the frame's instance has training frames)."""
    common = [k for k in train.arrays if k in test.arrays]
    arrays = {k: np.concatenate([train.arrays[k], test.arrays[k]]) for k in common}
    arrays["test"] = np.r_[np.zeros(len(train), bool), np.ones(len(test), bool)]
    arrays["seen"] = np.isin(arrays["instance"], train.instance)
    return FeatureTable(arrays)


@dataclass
class FeatureTable:
    """Features and labels of every frame found, concatenated (n frames).

    train_vector / query_vector (n, 2 gamma) float64, NaN where the frame had
    too few keypoints; *_eccentricity (n,); raw (n, s^2) uint8; template (n,
    3535) float32 (spm_model/methods/template.py); pose (n, 6) (rx, ry, rz degrees, t
    metres); K (n, 3, 3); width (n,) int64 pixels; label_measured (n, 6) bool;
    class_name, instance (n,) str (instance: source:class/name, unique per
    object); instance_id (n,) int64 (within its shard's spec); path_index (n,)
    int64; occlusion_fraction (n,) float32; occluder (n,) str (occluder_kind); shard (n,)
    str; frame (n,) int64; has_depth (n,) bool (a measured depth under the mask). Features are
    computed from what a camera sees: the visible mask where the shard has one. offgrid_table
    adds ``test`` and ``seen`` (n,) bool."""

    arrays: dict

    def __len__(self) -> int:
        return len(self.arrays["pose"])

    def __getattr__(self, name):
        try:
            return self.__dict__["arrays"][name]
        except KeyError:
            raise AttributeError(name) from None

    def subset(self, index) -> "FeatureTable":
        return FeatureTable({k: v[index] for k, v in self.arrays.items()})


def remove_stale_partials(shards: list[Path]) -> list[Path]:
    """Delete cache files half-written by processes of this host that are gone
    (a killed run); another host's, or a live process's, are left alone.

    Also where the cache goes: a shard folder whose ``.spm-features`` cannot be created or
    written caches in the per-user cache instead, said once in a warning (SpmWarning)."""
    removed, moved = [], []
    host = socket.gethostname()
    for shard_folder in sorted({Path(s).parent for s in shards}):
        folders = [shard_folder / CACHE_DIR]
        why = _unwritable(folders[0])
        if why is not None:
            folders.append(user_cache_folder(shard_folder))
            if _unwritable(folders[1]) is None:
                moved.append((folders[0], why, folders[1]))
        for folder in folders:
            for path in folder.glob(PARTIAL_PREFIX + "*.partial") if folder.is_dir() else []:
                parts = path.name.rsplit(".", 3)  # .NAME.npz . host . pid . partial
                if len(parts) != 4 or parts[1] != host or not parts[2].isdigit():
                    continue
                if pid_alive(int(parts[2])):
                    continue
                try:
                    path.unlink(missing_ok=True)
                    removed.append(path)
                except OSError:
                    pass  # a read-only folder: left as it is
    if moved:
        beside, why, user = moved[0]
        where = (f"{beside} ({why}); caching features in {user}" if len(moved) == 1 else
                 f"beside the shards of {len(moved)} folders (first: {beside}: {why}); caching features under "
                 f"{user.parent}")
        warnings.warn(f"cannot write the feature cache {where} instead (set SPM_CACHE_DIR to choose another "
                      "folder)", SpmWarning, stacklevel=2)
    return removed


@contextlib.contextmanager
def _removing_empty_caches(shards):
    """Run the block; if it fails, remove the cache folders it created that are still empty."""
    candidates = {f for s in shards for f in (Path(s).parent / CACHE_DIR, user_cache_folder(Path(s).parent))}
    new = {f: nearest_existing(f) for f in candidates if not f.exists()}
    try:
        yield
    except BaseException:
        for folder, base in new.items():
            while folder != base:
                try:
                    folder.rmdir()  # only when empty: another run's files are kept
                except OSError:
                    break
                folder = folder.parent
        raise


def progress_phase(progress, label: str, total=None, unit: str | None = "frame") -> None:
    """Start the next step of ``progress`` (None: nothing): its ``phase(label, total, unit)``
    (spm_data.jobs.progress.Progress), else a new ``total`` (a callable with one)."""
    if progress is not None:
        if hasattr(progress, "phase"):
            progress.phase(label, total, unit)
        else:
            progress.total = total


def _each(items, progress):
    for item in items:
        yield item
        if progress is not None:
            progress(1)


def load_features(folder, config: FeatureConfig = FeatureConfig(), *, progress=None, executor=None,
                  allow_partial: bool = False, what: str = "features") -> FeatureTable:
    """Extract (or reuse) the features of every shard under ``folder``, one job per
    shard on ``executor`` (spm_data.jobs.make_executor; default: this process); progress is a
    callable taking count deltas (progress_phase: "checking cached WHAT" and "reading WHAT"
    count shards, "WHAT" the frames extracted). allow_partial: read folders still being written
    (spm_data.io.folders.open_folder)."""
    shards = find_shards(folder, allow_partial)
    remove_stale_partials(shards)
    with _removing_empty_caches(shards):
        progress_phase(progress, f"checking cached {what}", len(shards), "shard")   # every shard's bytes verified
        paths = {s: cached(s, config) for s in _each(shards, progress)}   # where each shard's features are
        todo = [(str(s), config) for s, p in paths.items() if p is None]
        progress_phase(progress, what, sum(int(read_attrs(path)["frames"]) for path, _ in todo))
        executor = executor or LocalExecutor(workers=1, retries=1)
        outcomes = executor.run(extract_shard, todo, on_progress=progress)
        failed = [o for o in outcomes if o.error]
        if failed:
            first, error = Path(failed[0].job[0]), str(failed[0].error)
            where = "" if error.startswith(str(first)) else f"{first.name}: "  # shard errors name their shard
            raise SpmError(f"feature extraction failed for {len(failed)} shard(s); first: {where}{error}")
    paths.update({Path(o.job[0]): Path(o.result) for o in outcomes})
    tables = []
    progress_phase(progress, f"reading {what}", len(shards), "shard")
    for shard in _each(shards, progress):
        arrays = read_cache(paths[shard], shard_digest(shard), config)
        if arrays is None:   # changed since it was checked (another process): one line, not a traceback
            raise SpmError(f"the feature cache {paths[shard]} changed while it was read; run the command again")
        n = len(arrays["pose"])
        arrays["instance"] = np.char.add(np.char.add(arrays.pop("source"), ":"),
                                         np.char.add(np.char.add(arrays["class_name"], "/"),
                                                     arrays.pop("instance_name")))
        arrays["shard"] = np.full(n, str(shard))
        arrays["occluder"] = np.full(n, occluder_kind(shard))
        arrays["frame"] = np.arange(n, dtype=np.int64)
        tables.append(arrays)
    return FeatureTable({k: np.concatenate([t[k] for t in tables]) for k in tables[0]})

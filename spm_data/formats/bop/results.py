"""Pose estimates in BOP's results format (bop_toolkit's ``inout.save_bop_results``, version
bop19), and the targets file ``test_targets_bop19.json`` of a BOP export.

A results file is ``{method}_{dataset}-{split}.csv`` (bop_toolkit parses the name so: the method
without ``_``, the dataset without ``-`` or ``_``); its first line is the header
``scene_id,im_id,obj_id,score,R,t,time``, then one row per estimate: R the 9 numbers of the
rotation row-major, space-separated, t in millimetres, time in seconds or -1 (unknown). A frame
without an estimate gets no row. The (scene_id, im_id, obj_id) of a frame are those
``spm-data export bop`` gives it (bop/ids.py).

Targets: one entry per image, its target (the first object of the image's ``scene_gt.json``
list; a distractor, ``"role": "distractor"`` in objects.json, and an object without a model
(image-only ground truth) are never targets), with
``inst_count`` the instances of that object in the image: what bop_toolkit's
eval_bop19_pose.py scores against.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np

from spm_data.errors import SpmError
from spm_data.io.files import atomic_file

HEADER = "scene_id,im_id,obj_id,score,R,t,time"
TARGETS_FILE = "test_targets_bop19.json"
NAME_PART = re.compile(r"[A-Za-z0-9]+")          # a dataset or split name bop_toolkit can parse back
TARGET_KEYS = ("im_id", "inst_count", "obj_id", "scene_id")


def method_name(method: str) -> str:
    """``method`` as a results file name can carry it: every run of characters other than letters,
    digits and '-' (bop_toolkit splits on '_' and '.') becomes one '-'."""
    name = re.sub(r"[^A-Za-z0-9-]+", "-", str(method)).strip("-")
    if not name:
        raise SpmError(f"method name {method!r}: expected letters, digits or '-', got none; name the method")
    return name


def result_file_name(method: str, dataset: str = "spm", split: str = "test") -> str:
    """``{method}_{dataset}-{split}.csv``; SpmError (one line) for a dataset or split name
    bop_toolkit would not parse back."""
    for option, value in (("--bop-dataset", dataset), ("--bop-split", split)):
        if not NAME_PART.fullmatch(str(value)):
            raise SpmError(f"{option} {value!r}: expected letters and digits only (bop_toolkit reads result files "
                           f"as METHOD_DATASET-SPLIT.csv); got '-', '_' or another character; e.g. spm, test")
    return f"{method_name(method)}_{dataset}-{split}.csv"


def pose_rows(ids, labels, frames=None, *, scores=None, times=None) -> list[dict]:
    """Rows (dicts with scene_id, im_id, obj_id, score, R (3, 3), t (3,) mm, time) of the estimates
    ``labels`` ((n, 6): rx, ry, rz degrees, t metres; a row with a NaN is no estimate, so no row) of
    the frames ``frames`` ((n,) positions in the folder's frame order; default 0..n-1) whose BOP ids
    are ``ids`` (bop_ids.FrameIds). scores, times: (n,) per estimate (default 1 and -1)."""
    from spm_data.core.poses import label_to_pose

    labels = np.asarray(labels, dtype=np.float64).reshape(-1, 6)
    frames = np.arange(len(labels)) if frames is None else np.asarray(frames, dtype=np.int64)
    if len(frames) != len(labels):
        raise SpmError(f"expected one frame per estimate, got {len(frames)} frames for {len(labels)} estimates")
    if len(frames) and (frames.min() < 0 or frames.max() >= len(ids.obj_id)):
        raise SpmError(f"expected frame positions 0..{len(ids.obj_id) - 1}, got {int(frames.min())}.."
                       f"{int(frames.max())}; give the folder the estimates were made on")
    ok = np.isfinite(labels).all(axis=1)
    R, t = label_to_pose(labels[ok]) if ok.any() else (np.zeros((0, 3, 3)), np.zeros((0, 3)))
    scores = np.ones(len(labels)) if scores is None else np.asarray(scores, dtype=np.float64)
    times = np.full(len(labels), -1.0) if times is None else np.asarray(times, dtype=np.float64)
    rows = []
    for k, (f, score, time) in enumerate(zip(frames[ok], scores[ok], times[ok])):
        rows.append({"scene_id": int(ids.scene_id[f]), "im_id": int(ids.im_id[f]), "obj_id": int(ids.obj_id[f]),
                     "score": float(score), "R": R[k], "t": 1000.0 * t[k], "time": float(time)})
    rows.sort(key=lambda r: (r["scene_id"], r["im_id"], r["obj_id"]))
    return rows


def _numbers(values) -> str:
    return " ".join(repr(float(v)) for v in np.asarray(values, dtype=np.float64).ravel())


def save_bop_results(path, rows) -> Path:
    """Write ``rows`` (pose_rows) to the results file ``path`` as bop_toolkit's save_bop_results
    does (header, then one line per row), atomically."""
    lines = [HEADER]
    for r in rows:
        lines.append(f"{int(r['scene_id'])},{int(r['im_id'])},{int(r['obj_id'])},{float(r['score'])!r},"
                     f"{_numbers(r['R'])},{_numbers(r['t'])},{float(r.get('time', -1.0))!r}")
    try:
        with atomic_file(path) as tmp:
            Path(tmp).write_text("\n".join(lines))
    except OSError as exc:
        raise SpmError(f"could not write {path}: {exc.strerror or exc}; give a writable folder") from None
    return Path(path)


def load_bop_results(path) -> list[dict]:
    """The rows of a results file (R (3, 3), t (3,) mm); SpmError naming the file and line
    for one that is not in BOP's format."""
    try:
        lines = Path(path).read_text().splitlines()
    except OSError as exc:
        raise SpmError(f"{path}: cannot read it ({exc.strerror or exc}); give a BOP results .csv") from None
    rows = []
    for n, line in enumerate(lines, 1):
        if (n == 1 and line.strip() == HEADER) or not line.strip():
            continue
        parts = line.split(",")
        try:
            if len(parts) != 7:
                raise ValueError(f"{len(parts)} comma-separated fields")
            rows.append({"scene_id": int(parts[0]), "im_id": int(parts[1]), "obj_id": int(parts[2]),
                         "score": float(parts[3]), "R": np.array(parts[4].split(), float).reshape(3, 3),
                         "t": np.array(parts[5].split(), float).reshape(3), "time": float(parts[6])})
        except ValueError as exc:
            raise SpmError(f"{path} line {n}: expected scene_id,im_id,obj_id,score,R (9 numbers),t (3),time; "
                           f"got {exc}") from None
    return rows


def save_test_targets(path, targets) -> Path:
    """Write ``targets`` (dicts with im_id, inst_count, obj_id, scene_id) as bop_toolkit's
    test_targets_bop19.json, atomically."""
    payload = [{k: int(t[k]) for k in TARGET_KEYS} for t in targets]
    with atomic_file(path) as tmp:
        Path(tmp).write_text(json.dumps(payload))
    return Path(path)


def load_test_targets(path) -> list[dict]:
    """The entries of a test_targets_bop19.json; SpmError naming the file for a malformed one."""
    try:
        return [{k: int(t[k]) for k in TARGET_KEYS} for t in json.loads(Path(path).read_text())]
    except OSError as exc:
        raise SpmError(f"{path}: cannot read it ({exc.strerror or exc}); give a {TARGETS_FILE}") from None
    except (ValueError, TypeError, KeyError) as exc:
        raise SpmError(f"{path}: expected a list of {{{', '.join(TARGET_KEYS)}}}, got {type(exc).__name__}: "
                       f"{exc}; write it with save_test_targets") from None


def test_targets(root, split: str) -> list[dict]:
    """The targets of the split ``split`` of the BOP dataset at ``root``, read back from its
    scene_gt.json files and objects.json (module docstring), sorted by scene and image."""
    from spm_data.formats.bop.ids import load_objects

    objects = load_objects(Path(root))
    # Not targets: distractors, and objects without a model (imported frames): bop_toolkit's
    # errors need the model, so a target without one would stop its evaluation.
    distractors = {k for k, v in objects.items() if v.get("role") == "distractor"
                   or v.get("ground_truth") == "image-only"}
    targets = []
    for scene in sorted(p for p in (Path(root) / split).iterdir() if p.is_dir() and p.name.isdigit()):
        gt = json.loads((scene / "scene_gt.json").read_text())
        for im, entries in gt.items():
            if not entries or int(entries[0]["obj_id"]) in distractors:
                continue
            obj = int(entries[0]["obj_id"])
            targets.append({"im_id": int(im), "inst_count": sum(int(e["obj_id"]) == obj for e in entries),
                            "obj_id": obj, "scene_id": int(scene.name)})
    return sorted(targets, key=lambda t: (t["scene_id"], t["im_id"]))


test_targets.__test__ = False   # not a pytest test, despite its name


def write_test_targets(root, split: str) -> Path:
    """``root/TARGETS_FILE`` from the split's ground truth (test_targets)."""
    return save_test_targets(Path(root) / TARGETS_FILE, test_targets(root, split))

"""Our BOP export against bop_toolkit's own scripts: how many ground-truth entries differ.

Copies the export EXPORT to a scratch folder, registers it with bop_toolkit as the dataset
"spm" (its obj_ids, splits, image size, from the export's files), runs there, in bop_toolkit's
own Python (``--python``; nothing of bop_toolkit is imported here):

* ``scripts/calc_gt_masks.py``  -> ``mask/``, ``mask_visib/``   (vispy, image size, delta 15 mm)
* ``scripts/calc_gt_info.py``   -> ``scene_gt_info.json``        (vispy, 3x canvas, bop19, 15 mm)
* ``scripts/calc_gt_coco.py``   -> ``scene_gt_coco.json``        (all ground truth, amodal boxes)
* ``scripts/calc_model_info.py`` on ``models/`` and on ``models_eval/`` -> ``models_info.json``

and prints, per file kind, how many entries were compared and how many differ (per field),
with the first few differences. COCO is bop_toolkit's whole chain (its masks and its
scene_gt_info), compared annotation by annotation, dates left out; models_info compares the
keys calc_model_info writes (our symmetries are ours alone).

bop_toolkit's scripts take their settings from a ``p = {...}`` dict at their top and their
datasets from ``dataset_params``: a small runner (written to the scratch folder) adds
``p.update(...)`` after that dict and answers ``dataset_params`` for "spm" from the export.

    python benchmarks/bop_toolkit_check.py EXPORT --bop-toolkit /path/to/bop_toolkit \\
        --python /path/to/bop-venv/bin/python [--work DIR] [--show 5]

Rendering: vispy over EGL; EGL_PLATFORM=surfaceless is set when unset (a machine without a display).
Progress on stderr (a line per script, with how long it has run).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from bop_registration import DATASET, REGISTRATION, write_description  # noqa: E402

MODEL_INFO_KEYS = ("diameter", "min_x", "min_y", "min_z", "size_x", "size_y", "size_z")
INFO_KEYS = ("px_count_all", "px_count_valid", "px_count_visib", "visib_fract", "bbox_obj", "bbox_visib")

RUNNER = r'''
"""Runs one bop_toolkit script on the dataset "spm" (written by bop_toolkit_check.py)."""
import ast, json, os, sys
from os.path import join

script, overrides = sys.argv[1], json.loads(sys.argv[2])
from bop_toolkit_lib import dataset_params

REGISTRATION = __REGISTRATION__

exec(REGISTRATION, vars(dataset_params))   # bop_registration.REGISTRATION, written into this file
tree = ast.parse(open(script).read(), script)
at = next(i for i, node in enumerate(tree.body) if isinstance(node, ast.Assign)
          and any(isinstance(t, ast.Name) and t.id == "p" for t in node.targets))
tree.body.insert(at + 1, ast.parse("p.update(__OVERRIDES__)").body[0])
ast.fix_missing_locations(tree)
sys.argv = [script] + sys.argv[3:]
exec(compile(tree, script, "exec"), {"__name__": "__main__", "__file__": script, "__OVERRIDES__": overrides})
'''


def _splits(export: Path) -> list[str]:
    return sorted(p.name for p in export.iterdir() if p.is_dir() and p.name not in ("models", "models_eval"))


def _split_args(split: str) -> tuple[str, str | None]:
    name, _, kind = split.partition("_")
    return name, kind or None


def _register(export: Path, copy: Path, splits: list[str]) -> None:
    """The dataset's description (bop_registration) and the targets file the scripts open, in ``copy``."""
    scenes = write_description(export, copy, splits)["scene_ids"]
    targets = []
    for split in splits:
        for scene in scenes[split]:
            gt = json.loads((export / split / f"{scene:06d}" / "scene_gt.json").read_text())
            for im, objects in gt.items():
                for obj_id in sorted({o["obj_id"] for o in objects}):
                    targets.append({"scene_id": scene, "im_id": int(im), "obj_id": obj_id,
                                    "inst_count": sum(o["obj_id"] == obj_id for o in objects)})
    (copy / "test_targets_bop19.json").write_text(json.dumps(targets))


def _run(python, toolkit: Path, work: Path, script: str, overrides: dict, argv=(), what="") -> None:
    from spm_data.jobs.progress import stage

    env = dict(os.environ, PYTHONPATH=str(toolkit), BOP_PATH=str(work / "datasets"), PYOPENGL_PLATFORM="egl")
    env.setdefault("EGL_PLATFORM", "surfaceless")
    cmd = [python, str(work / "runner.py"), str(toolkit / "scripts" / script), json.dumps(overrides), *argv]
    with stage(f"bop_toolkit_check: {script}{what}"):
        done = subprocess.run(cmd, env=env, cwd=work, capture_output=True, text=True)
    if done.returncode != 0:
        sys.exit(f"bop_toolkit_check: {script} failed ({done.returncode}):\n{done.stdout[-3000:]}\n"
                 f"{done.stderr[-3000:]}")


def _short(value, room: int = 60) -> str:
    text = str(value)
    return text if len(text) <= room else text[:room] + f"... ({len(text)} characters)"


class Tally:
    """Entries compared and differing, per field, with the first few differences."""

    def __init__(self, kind: str, show: int, label: str = "per field"):
        self.kind, self.show, self.label = kind, show, label
        self.entries, self.differ, self.fields, self.examples = 0, 0, {}, []

    def compare(self, where: str, ours: dict, theirs: dict, keys) -> None:
        self.entries += 1
        bad = [k for k in keys if ours.get(k) != theirs.get(k)]
        for k in bad:
            self.fields[k] = self.fields.get(k, 0) + 1
        if bad:
            self.differ += 1
            if len(self.examples) < self.show:
                self.examples.append(f"{where}: " + "; ".join(f"{k} ours {_short(ours.get(k))} theirs "
                                                             f"{_short(theirs.get(k))}" for k in bad))

    def count(self, where: str, differing: int) -> None:
        """One mask file compared: ``differing`` pixels."""
        self.entries += 1
        if differing:
            self.differ += 1
            self.fields["pixels"] = self.fields.get("pixels", 0) + differing
            if len(self.examples) < self.show:
                self.examples.append(f"{where}: {differing} pixel{'s differ' if differing > 1 else ' differs'}")

    def report(self, unit="entries") -> None:
        fields = ", ".join(f"{k} {n}" for k, n in sorted(self.fields.items())) or "none"
        print(f"{self.kind}: {self.entries} {unit} compared, {self.differ} differ ({self.label}: {fields})")
        for line in self.examples:
            print(f"    {line}")


def _mask(path: Path) -> np.ndarray:
    import cv2

    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise SystemExit(f"bop_toolkit_check: cannot read {path}")
    return image > 0


def compare(export: Path, copy: Path, splits: list[str], show: int) -> dict:
    info, masks, coco, models = (Tally("scene_gt_info.json", show), Tally("mask/ + mask_visib/ PNGs", show, "in all"),
                                 Tally("scene_gt_coco.json", show), Tally("models_info.json", show))
    for split in splits:
        for scene in sorted(p.name for p in (export / split).iterdir() if p.is_dir()):
            ours_dir, theirs_dir = export / split / scene, copy / split / scene
            ours = json.loads((ours_dir / "scene_gt_info.json").read_text())
            theirs = json.loads((theirs_dir / "scene_gt_info.json").read_text())
            for im in sorted(ours, key=int):
                for k, (a, b) in enumerate(zip(ours[im], theirs.get(im, []))):
                    info.compare(f"{split}/{scene} im {im} gt {k}", a, b, INFO_KEYS)
                    for sub in ("mask", "mask_visib"):
                        name = f"{int(im):06d}_{k:06d}.png"
                        masks.count(f"{split}/{scene}/{sub}/{name}",
                                    int((_mask(ours_dir / sub / name) != _mask(theirs_dir / sub / name)).sum()))
                if len(ours[im]) != len(theirs.get(im, [])):
                    info.compare(f"{split}/{scene} im {im}", {"objects": len(ours[im])},
                                 {"objects": len(theirs.get(im, []))}, ["objects"])
            a_coco = json.loads((ours_dir / "scene_gt_coco.json").read_text())
            b_coco = json.loads((theirs_dir / "scene_gt_coco.json").read_text())
            coco.compare(f"{split}/{scene} categories", {"categories": a_coco["categories"]},
                         {"categories": b_coco["categories"]}, ["categories"])
            undated = lambda image: {k: v for k, v in image.items() if k != "date_captured"}  # noqa: E731
            for a, b in zip(a_coco["images"], b_coco["images"]):
                coco.compare(f"{split}/{scene} image {a['id']}", undated(a), undated(b), sorted(set(a) | set(b)))
            a_ann = {(x["image_id"], x["id"]): x for x in a_coco["annotations"]}
            b_ann = {(x["image_id"], x["id"]): x for x in b_coco["annotations"]}
            for key in sorted(set(a_ann) | set(b_ann)):
                a, b = a_ann.get(key, {}), b_ann.get(key, {})
                coco.compare(f"{split}/{scene} annotation {key[1]} (image {key[0]})", a, b, sorted(set(a) | set(b)))
            if len(a_coco["images"]) != len(b_coco["images"]):
                coco.compare(f"{split}/{scene}", {"images": len(a_coco["images"])}, {"images": len(b_coco["images"])},
                             ["images"])
    for folder in ("models", "models_eval"):
        ours = json.loads((export / folder / "models_info.json").read_text())
        theirs = json.loads((copy / folder / "models_info.json").read_text())
        for obj in sorted(set(ours) | set(theirs), key=int):
            models.compare(f"{folder} obj {obj}", ours.get(obj, {}), theirs.get(obj, {}), MODEL_INFO_KEYS)
    info.report("objects in frames")
    masks.report("mask files")
    coco.report("categories lists, images and annotations")
    models.report("objects")
    return {"info": info.differ, "masks": masks.differ, "coco": coco.differ, "models": models.differ}


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("export", type=Path, help="a folder written by spm-data export bop")
    parser.add_argument("--bop-toolkit", type=Path, required=True, help="a checkout of thodan/bop_toolkit")
    parser.add_argument("--python", required=True, help="a Python with bop_toolkit's requirements (vispy, pyopengl)")
    parser.add_argument("--work", type=Path, help="scratch folder (default: a temporary one, removed)")
    parser.add_argument("--show", type=int, default=5, help="differences to print per file kind")
    args = parser.parse_args(argv)
    export, toolkit = args.export.resolve(), args.bop_toolkit.resolve()
    if not (export / "camera.json").is_file():
        sys.exit(f"bop_toolkit_check: {export} is not a BOP export (no camera.json)")
    if not (toolkit / "scripts" / "calc_gt_info.py").is_file():
        sys.exit(f"bop_toolkit_check: {toolkit} is not a bop_toolkit checkout (no scripts/calc_gt_info.py)")
    with tempfile.TemporaryDirectory() as tmp:
        work = (args.work or Path(tmp)).resolve()
        copy = work / "datasets" / DATASET
        shutil.rmtree(copy, ignore_errors=True)
        shutil.copytree(export, copy)
        (work / "runner.py").write_text(RUNNER.replace("__REGISTRATION__", repr(REGISTRATION)))
        splits = _splits(export)
        _register(export, copy, splits)
        common = ["--dataset", DATASET, "--datasets_path", str(work / "datasets")]
        for split in splits:
            name, kind = _split_args(split)
            where = ["--dataset_split", name] + (["--dataset_split_type", kind] if kind else [])
            _run(args.python, toolkit, work, "calc_gt_masks.py", {}, common + where, f" on {split}")
            _run(args.python, toolkit, work, "calc_gt_info.py",
                 {"dataset": DATASET, "dataset_split": name, "dataset_split_type": kind, "modality": None,
                  "sensor": None, "datasets_path": str(work / "datasets"), "renderer_type": "vispy", "delta": 15,
                  "vis_visibility_masks": False}, what=f" on {split}")
            _run(args.python, toolkit, work, "calc_gt_coco.py", {},
                 common + where + ["--use_all_gt", "--bbox_type", "amodal"], f" on {split}")
        for model_type in (None, "eval"):
            _run(args.python, toolkit, work, "calc_model_info.py",
                 {"dataset": DATASET, "model_type": model_type, "datasets_path": str(work / "datasets")},
                 what=f" on models{'_' + model_type if model_type else ''}/")
        return compare(export, copy, splits, args.show)


if __name__ == "__main__":
    main()

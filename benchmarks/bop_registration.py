"""The dataset "spm" (an ``spm-data export bop`` folder) registered with a copy of bop_toolkit,
one way for every benchmark that runs bop_toolkit's own scripts (bop_eval.py, bop_toolkit_check.py).

``REGISTRATION`` is Python for bop_toolkit's ``bop_toolkit_lib/dataset_params.py`` namespace
(appended to that file, or executed in the module's namespace): it answers get_model_params and
get_split_params for "spm" from ``<datasets_path>/spm/spm_dataset.json`` (obj_ids, symmetric
objects, image size, scene ids per split; :func:`write_description` writes it) with LM's classic
layout for the paths, and every other dataset as before. Nothing of bop_toolkit is imported here.
"""

from __future__ import annotations

import json
from pathlib import Path

DATASET = "spm"

REGISTRATION = r'''

# --- Registered by spm's benchmarks (bop_registration.py): the dataset "spm" (an spm-data export
# bop folder), described by <datasets_path>/spm/spm_dataset.json; every other dataset as before.
import json as _spm_json
from os.path import join as _spm_join

_spm_get_model_params, _spm_get_split_params = get_model_params, get_split_params


def _spm_description(datasets_path):
    with open(_spm_join(datasets_path, "spm", "spm_dataset.json")) as fh:
        return _spm_json.load(fh)


def get_model_params(datasets_path, dataset_name, model_type=None):
    if dataset_name != "spm":
        return _spm_get_model_params(datasets_path, dataset_name, model_type)
    spec = _spm_description(datasets_path)
    folder = _spm_join(datasets_path, "spm", "models" + ("_" + model_type if model_type else ""))
    return {"obj_ids": spec["obj_ids"], "symmetric_obj_ids": spec["symmetric_obj_ids"],
            "model_tpath": _spm_join(folder, "obj_{obj_id:06d}.ply"),
            "models_info_path": _spm_join(folder, "models_info.json")}


def get_split_params(datasets_path, dataset_name, split, split_type=None):
    if dataset_name != "spm":
        return _spm_get_split_params(datasets_path, dataset_name, split, split_type)
    spec = _spm_description(datasets_path)
    p = _spm_get_split_params(datasets_path, "lm", split, split_type)   # LM's classic layout, paths moved
    old, new = _spm_join(datasets_path, "lm"), _spm_join(datasets_path, "spm")
    p = {k: (v.replace(old, new, 1) if isinstance(v, str) else v) for k, v in p.items()}
    full = split + ("_" + split_type if split_type else "")
    p.update(name="spm", im_size=tuple(spec["im_size"]), scene_ids=spec["scene_ids"][full],
             depth_range=None, azimuth_range=None, elev_range=None)
    return p
'''


def description(export: Path, splits: list[str]) -> dict:
    """What REGISTRATION reads of an export: obj_ids and the symmetric ones (models_info.json),
    the image size (camera.json) and each split's scene ids (its folders)."""
    camera = json.loads((export / "camera.json").read_text())
    info = json.loads((export / "models" / "models_info.json").read_text())
    symmetric = [int(k) for k, v in info.items() if v.get("symmetries_discrete") or v.get("symmetries_continuous")]
    return {"obj_ids": sorted(int(k) for k in info), "symmetric_obj_ids": sorted(symmetric),
            "im_size": [camera["width"], camera["height"]],
            "scene_ids": {s: sorted(int(p.name) for p in (export / s).iterdir() if p.is_dir()) for s in splits}}


def write_description(export: Path, dataset_dir: Path, splits: list[str]) -> dict:
    """``description`` of ``export`` written to ``dataset_dir``/spm_dataset.json (``dataset_dir``:
    <datasets_path>/spm, the export's copy); returns it."""
    spec = description(export, splits)
    (dataset_dir / "spm_dataset.json").write_text(json.dumps(spec))
    return spec

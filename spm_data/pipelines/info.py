"""Human-readable summaries of a shard or a shard folder (``spm-data info``)."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np

from spm_data.errors import ShardError, SpmWarning
from spm_data.io.folders import open_folder
from spm_data.io.shards import MANIFEST, read_attrs, read_manifest, read_shard, shard_layout


def _device(attrs: dict) -> str:
    """", on DEVICE" for a shard whose renderer recorded where it rendered (Blender's Cycles)."""
    try:
        device = json.loads(str(attrs.get("renderer_settings") or "{}")).get("device")
    except (ValueError, AttributeError):
        device = None
    return f", on {device}" if device else ""


def shard_info(path) -> str:
    attrs = read_attrs(path)
    lines = [f"shard {path}", f"  schema v{attrs['schema_version']}, {attrs['frames']} frames, "
             f"{attrs.get('width')}x{attrs.get('height')}, renderer {attrs.get('renderer')} "
             f"({attrs.get('renderer_version', '')}{_device(attrs)}), seed {attrs.get('seed')}"]
    for name, (shape, dtype) in shard_layout(path).items():
        lines.append(f"  {name:<20} {str(shape):<22} {dtype}")
    meta = read_shard(path, ["class_name", "instance_name", "source", "azimuth", "elevation", "distance",
                             "occlusion_fraction"])
    if len(meta["class_name"]):
        classes, counts = np.unique(meta["class_name"].astype(str), return_counts=True)
        lines.append("  classes: " + ", ".join(f"{c} ({k})" for c, k in zip(classes, counts)))
        lines.append("  instances: " + ", ".join(sorted(set(meta["instance_name"].astype(str)))))
        lines.append("  sources: " + ", ".join(sorted(set(meta["source"].astype(str)))))
        for key, unit in (("azimuth", "deg"), ("elevation", "deg"), ("distance", "m"), ("occlusion_fraction", "")):
            v = meta[key]
            lines.append(f"  {key}: {v.min():.3g}..{v.max():.3g} {unit}".rstrip())
    return "\n".join(lines)


def folder_info(folder) -> str:
    folder = Path(folder)
    with warnings.catch_warnings(record=True) as caught:  # info describes a partial folder, noting its gaps
        warnings.simplefilter("always", SpmWarning)
        shards = open_folder(folder, allow_partial=True).shards
    lines = [f"folder {folder}: {len(shards)} shards"] + [f"{NOTE}{w.message}" for w in caught]
    if (folder / MANIFEST).is_file():
        m = read_manifest(folder)
        lines.append(f"  manifest: {m.get('frames', '?')} frames in {len(m['shards'])} shards")
        for c, k in m.get("classes", {}).items():
            lines.append(f"    {c:<24} {k} frames")
    else:
        lines.append(f"  no {MANIFEST} (an interrupted or foreign folder?)")
    total = 0
    for p in shards:
        a = read_attrs(p)
        total += int(a["frames"])
        lines.append(f"  {p.name:<28} {a['frames']:>6} frames  {p.stat().st_size / 1e6:8.2f} MB  "
                     f"{a.get('renderer', '')}")
    lines.append(f"  total: {total} frames")
    return "\n".join(lines)


def info_text(path) -> str:
    """What `spm-data info` prints for ``path``: a shard's fields, or a folder's shards and classes."""
    path = Path(path)
    if path.is_dir():
        return folder_info(path)
    if path.is_file():
        return shard_info(path)
    raise ShardError(f"no such shard or folder: {path}")


NOTE = "  note: "


def check_noted(path, text: str) -> None:
    """ShardError (one line, after the description is printed) when ``text`` (info_text) noted a
    gap: a listed shard missing, cut short or damaged, a shard the manifest does not list, no
    manifest. info still describes what it can, but does not exit 0 on a folder that is not whole."""
    notes = sum(line.startswith(NOTE) for line in text.splitlines())
    if notes:
        raise ShardError(f"{path}: {notes} problem{'s' if notes != 1 else ''} noted above; the folder is not whole: "
                         f"run `spm-data validate {path}` for the details")

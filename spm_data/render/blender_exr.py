"""Blender's frames read back: the multi-layer EXR a render writes, as the arrays a Renderer returns.

Blender 5 writes one EXR part per pass (Combined, Depth, Object Index, Normal when
asked); with a render border the file holds only the border, which is put back
into a full frame here (blender_scene.uncrop).
"""

from __future__ import annotations

import numpy as np

from spm_data.errors import RenderError
from spm_data.render.blender_scene import srgb_encode, uncrop

NO_HIT_DEPTH = 1e9  # Blender writes 1e10 where no surface was hit
INSTALL_HINT = "install it with: pip install 'spm[blender]' (bpy 5.0.x, Python 3.11)"


def import_openexr():
    """The OpenEXR module, or a RenderError saying how to install it."""
    try:
        import OpenEXR
    except ImportError as exc:
        raise RenderError(f"the OpenEXR package is not installed ({exc}); {INSTALL_HINT}") from None
    return OpenEXR


def read_frame(exr, path: str, *, normals: bool, distractor_slots: bool, crop, height: int, width: int) -> dict:
    """The frame in the EXR at ``path`` (read with the OpenEXR module ``exr``), full size (height, width):
    rgb (H, W, 3) uint8 sRGB, alpha (H, W) float32, depth (H, W) float32 metres (0 where nothing
    counts: off the target, or off every object when ``distractor_slots``), mask (H, W) uint8,
    ids (H, W) uint8 pass indices (0 background, 1 target, 2 + k distractor k), and with
    ``normals`` world_normals (H, W, 3) float32 in Blender's world frame. ``crop`` (x0, y0, x1, y1)
    is the render border the file holds, or None for a full frame."""
    try:
        with exr.File(path) as f:
            channels = {name: ch for part in f.parts for name, ch in part.channels.items()}
            combined = np.asarray(channels["ViewLayer.Combined"].pixels, dtype=np.float32)
            z = np.asarray(channels["ViewLayer.Depth.Z"].pixels, dtype=np.float32)
            index = channels.get("ViewLayer.Object Index.X")
            index = None if index is None else np.asarray(index.pixels)
            world_normals = None
            if normals:
                world_normals = np.stack([np.asarray(channels[f"ViewLayer.Normal.{c}"].pixels, np.float32)
                                          for c in "XYZ"], axis=-1)
    except (OSError, KeyError, RuntimeError) as exc:
        raise RenderError(f"could not read Blender's EXR output ({type(exc).__name__}: {exc})") from None
    hit = z < NO_HIT_DEPTH
    ids = np.where(hit, np.rint(index), 0).astype(np.uint8) if index is not None else hit.astype(np.uint8)
    mask = ids == 1 if index is not None else hit
    depth = np.where(hit if distractor_slots else mask, z, 0.0).astype(np.float32)
    alpha = np.clip(combined[..., 3], 0.0, 1.0)
    out = {"rgb": srgb_encode(combined[..., :3]), "alpha": alpha.astype(np.float32),
           "depth": depth, "mask": mask.astype(np.uint8), "ids": ids}
    if normals:
        out["world_normals"] = world_normals
    if z.shape != (height, width):
        x0, y0, x1, y1 = crop or (0, 0, 0, 0)
        if z.shape != (y1 - y0, x1 - x0):
            raise RenderError(f"Blender's EXR is {z.shape[1]}x{z.shape[0]}, expected {width}x{height} "
                              f"or its render border {x1 - x0}x{y1 - y0}")
        out = uncrop(out, crop, height, width)
    return out

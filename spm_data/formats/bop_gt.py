"""BOP ground truth per frame, by the rules of bop_toolkit's ``scripts/calc_gt_info.py``.

``scene_gt_info.json`` (:func:`gt_info`): calc_gt_info renders the object on a canvas
three times the image's size (the image in its middle), so ``px_count_all`` and
``bbox_obj`` count the whole silhouette, also where the image border cuts it:
``visib_fract`` = visible pixels in the image / pixels of the whole silhouette, and
``bbox_obj`` is not clipped to the image (x or y may be negative). We get that
canvas from the shard's mask in the middle and the mesh's silhouette at pixel
centres (core/raster.py) around it (:func:`full_silhouette`).

Depth PNGs (:func:`depth_scale_for`): uint16 × ``depth_scale`` = mm; the scale is
chosen per image so the farthest depth fits (BOP stores it per image).
"""

from __future__ import annotations

import numpy as np

from spm_data.errors import SpmError
from spm_data.core.raster import NEAR, project, silhouette

# mm per depth unit: the finest of these whose range (65535 units) holds the image's farthest
# depth. 0.1 mm (BOP's usual choice) reaches 6.5535 m; 10 mm reaches 655 m.
DEPTH_SCALES = (0.1, 0.2, 0.5, 1.0, 2.0, 5.0, 10.0)
# An occluder's depth, as a fraction of the object's nearest point: far enough in front (20 %,
# 100 mm at 0.5 m) that bop_toolkit's visibility test (15 mm tolerance) sees the object hidden.
OCCLUDER_DEPTH = 0.8
NO_BOX = [-1, -1, -1, -1]


def depth_scale_for(depth_m: np.ndarray) -> float:
    """The finest of DEPTH_SCALES (mm per unit) whose 65535 units hold the largest of ``depth_m``
    (metres, any shape); SpmError (one line) when even the coarsest does not."""
    far_mm = float(np.max(depth_m, initial=0.0)) * 1000.0
    for scale in DEPTH_SCALES:
        if round(far_mm / scale) <= 65535:
            return scale
    raise SpmError(f"a depth of {far_mm / 1000:.1f} m does not fit a BOP depth PNG even at "
                   f"{DEPTH_SCALES[-1]:g} mm per unit (at most {65535 * DEPTH_SCALES[-1] / 1000:.0f} m); "
                   "render the objects nearer")


def depth_units(depth_m: np.ndarray, scale: float) -> np.ndarray:
    """(H, W) uint16 PNG values for ``depth_m`` (H, W) metres at ``scale`` mm per unit
    (from depth_scale_for, so nothing is clipped)."""
    units = np.round(np.asarray(depth_m, dtype=np.float64) * 1000.0 / scale)
    return units.astype(np.uint16)


def bbox(mask: np.ndarray, offset=(0, 0)) -> list[int]:
    """[x, y, w, h] of ``mask``'s pixels as calc_gt_info writes it: w = x_max - x_min (no + 1;
    COCO's boxes add 1), minus ``offset`` (x, y) pixels; NO_BOX when empty."""
    ys, xs = np.nonzero(mask)
    if len(ys) == 0:
        return list(NO_BOX)
    return [int(xs.min() - offset[0]), int(ys.min() - offset[1]), int(xs.max() - xs.min()), int(ys.max() - ys.min())]


def depth_with_occluders(depth: np.ndarray, mask: np.ndarray, visible: np.ndarray) -> np.ndarray:
    """Depth (H, W) metres where our 2-D occluders hide the object: there, a flat occluder at
    OCCLUDER_DEPTH of the object's nearest depth. BOP's tools (calc_gt_info, VSD) find what is
    visible from depth, so without it they would call every occluded object fully visible."""
    hidden = mask & ~visible
    if not hidden.any():
        return depth
    out = depth.copy()
    out[hidden] = OCCLUDER_DEPTH * depth[mask & (depth > 0)].min()
    return out


def full_silhouette(mask: np.ndarray, mesh, K, R, t) -> np.ndarray:
    """(3H, 3W) bool: calc_gt_info's canvas, the image (H, W) in its middle. ``mask`` (H, W)
    bool is the frame's full mask (kept exactly, as rendered); around it, the silhouette of
    ``mesh`` (a TexturedMesh, or None when the frame has no mesh: nothing around) posed by
    ``R`` (3, 3), ``t`` (3,) metres (object to OpenCV camera) through ``K`` (3, 3, OpenCV)."""
    h, w = mask.shape
    canvas = np.zeros((3 * h, 3 * w), dtype=bool)
    if mesh is not None:
        uv, z = project(mesh.vertices, K, R, t)
        inside = (uv[:, 0] >= -0.5) & (uv[:, 0] < w - 0.5) & (uv[:, 1] >= -0.5) & (uv[:, 1] < h - 0.5)
        if not inside.all() and z.min() >= NEAR:   # some triangle may cover a pixel centre outside
            shifted = np.array(K, dtype=np.float64)
            shifted[:2, 2] += (w, h)
            canvas = silhouette(mesh.vertices, mesh.faces, shifted, R, t, 3 * h, 3 * w)
    canvas[h:2 * h, w:2 * w] = mask
    return canvas


def gt_info(canvas: np.ndarray, visible: np.ndarray, depth: np.ndarray) -> dict:
    """One object's ``scene_gt_info.json`` entry: ``canvas`` (3H, 3W) bool from full_silhouette,
    ``visible`` (H, W) bool its visible pixels, ``depth`` (H, W) metres the exported scene depth."""
    h, w = visible.shape
    full, vis = int(canvas.sum()), int(visible.sum())
    in_image = canvas[h:2 * h, w:2 * w]
    return {"bbox_obj": bbox(canvas, offset=(w, h)) if vis else list(NO_BOX),  # no box for an unseen object
            "bbox_visib": bbox(visible), "px_count_all": full,
            "px_count_valid": int((depth[in_image] > 0).sum()), "px_count_visib": vis,
            "visib_fract": vis / full if full else 0.0}

"""BOP ground truth per object and frame, as bop_toolkit's scripts compute it from the export.

``scripts/calc_gt_info.py`` renders each object alone (vispy, on Mesa's llvmpipe) on a
canvas three times the image's size, the image in its middle, turns depths into distances
along the rays, and calls a pixel visible where the object is at most 15 mm behind the
scene's depth PNG or the PNG has no depth ("bop19"); ``scripts/calc_gt_masks.py`` does the
same at the image's size for ``mask/`` and ``mask_visib/``. :func:`object_gt` computes both
by those rules from what the export writes (model PLY, ``cam_K``, pose, depth PNG), with
spm_data.core.raster.render_depth drawing a model as that renderer does (the
rasteriser a cluttered frame's amodal mask comes from too): vispy's matrices (near and far
planes at the model's bounding box), the vertex shader in float32, draw's clipping at the
frustum's planes (no guard band), 1/256-pixel vertex snapping and the fill rule of
llvmpipe's rasteriser, so that the counts, boxes and masks agree to the pixel, also for
objects cut by the image border. (A GPU driver snaps and clips its own way: there an
edge pixel or two may go the other way.)

Depth PNGs (:func:`depth_scale_for`): uint16 × ``depth_scale`` = mm; the scale is chosen
per image so the farthest depth fits (BOP stores it per image).
"""

from __future__ import annotations

import numpy as np

from spm_data.core.raster import render_depth
from spm_data.errors import SpmError

# mm per depth unit: the finest of these whose range (65535 units) holds the image's farthest
# depth. 0.1 mm (BOP's usual choice) reaches 6.5535 m; 10 mm reaches 655 m.
DEPTH_SCALES = (0.1, 0.2, 0.5, 1.0, 2.0, 5.0, 10.0)
# An occluder's depth, as a fraction of the object's nearest point: far enough in front (20 %,
# 100 mm at 0.5 m) that bop_toolkit's visibility test (15 mm tolerance) sees the object hidden.
OCCLUDER_DEPTH = 0.8
NO_BOX = [-1, -1, -1, -1]
DELTA_MM = 15.0          # calc_gt_info's and calc_gt_masks' visibility tolerance
_F = np.float32


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
    if not hidden.any() or not (mask & (depth > 0)).any():
        return depth
    out = depth.copy()
    stand_in = OCCLUDER_DEPTH * depth[mask & (depth > 0)].min()
    # Nearer things already in the depth (a 3-D distractor over a rectangle) stay in front.
    out[hidden] = np.where(depth[hidden] > 0, np.minimum(depth[hidden], stand_in), stand_in)
    return out


# --------------------------------------------------------------------------- calc_gt_info's and calc_gt_masks' rules

def distances(depth_mm: np.ndarray, K) -> np.ndarray:
    """(H, W) float64 mm from the camera centre, of ``depth_mm`` (H, W) along z, through ``K``
    (3, 3, BOP's convention), by bop_toolkit's formula (misc.depth_im_to_dist_im_fast)."""
    h, w = depth_mm.shape
    xs, ys = np.meshgrid(np.arange(w), np.arange(h))
    px, py = (xs - K[0, 2]) / np.float64(K[0, 0]), (ys - K[1, 2]) / np.float64(K[1, 1])
    return np.sqrt(np.multiply(px, depth_mm) ** 2 + np.multiply(py, depth_mm) ** 2 + depth_mm.astype(np.float64) ** 2)


def visible_mask(dist_scene: np.ndarray, dist_model: np.ndarray, delta: float = DELTA_MM) -> np.ndarray:
    """(H, W) bool, bop19 visibility: the model's distance at most ``delta`` mm behind the scene's,
    or the scene without depth, where the model is (differences in float32, as bop_toolkit's)."""
    diff = dist_model.astype(_F) - dist_scene.astype(_F)
    return ((diff <= delta) | (dist_scene == 0)) & (dist_model > 0)


def png_depth_mm(units: np.ndarray, scale: float) -> np.ndarray:
    """(H, W) float32 mm of a depth PNG's ``units`` at ``scale`` mm per unit, as inout.load_depth
    and the scripts read it (float32 times the scale)."""
    return units.astype(_F) * scale


def object_gt(vertices_mm, faces, K, R, t_mm, scene_depth_mm) -> tuple[dict, np.ndarray, np.ndarray]:
    """One object's (scene_gt_info entry, mask (H, W) bool, mask_visib (H, W) bool), as
    calc_gt_info and calc_gt_masks compute them: the model (``vertices_mm`` (V, 3) float32 as its
    PLY stores them, ``faces`` (F, 3)) at ``R`` (3, 3), ``t_mm`` (3,) through ``K`` (3, 3, BOP's
    convention), seen against the scene's ``scene_depth_mm`` (H, W, png_depth_mm)."""
    h, w = scene_depth_mm.shape
    large = render_depth(vertices_mm, faces, K, R, t_mm, 3 * w, 3 * h, offset=(w, h))
    dist_scene = distances(scene_depth_mm, K)
    dist_gt = distances(large[h:2 * h, w:2 * w], K)
    visib = visible_mask(dist_scene, dist_gt)
    full, seen = large > 0, int(visib.sum())
    info = {"bbox_obj": bbox(full, offset=(w, h)) if seen else list(NO_BOX),
            "bbox_visib": bbox(visib), "px_count_all": int(full.sum()),
            "px_count_valid": int((dist_scene[dist_gt > 0] > 0).sum()), "px_count_visib": seen,
            "visib_fract": seen / float(full.sum()) if full.any() else 0.0}
    dist_small = distances(render_depth(vertices_mm, faces, K, R, t_mm, w, h), K)
    return info, dist_small > 0, visible_mask(dist_scene, dist_small)


def image_gt(mask: np.ndarray, visible: np.ndarray, depth: np.ndarray) -> dict:
    """The scene_gt_info entry of an object without a model (an imported frame): its ``mask``
    (H, W) bool inside the image is all there is of it; ``visible`` (H, W) bool, ``depth``
    (H, W) metres the exported depth."""
    full, vis = int(mask.sum()), int(visible.sum())
    return {"bbox_obj": bbox(mask) if vis else list(NO_BOX), "bbox_visib": bbox(visible), "px_count_all": full,
            "px_count_valid": int((depth[mask] > 0).sum()), "px_count_visib": vis,
            "visib_fract": vis / full if full else 0.0}

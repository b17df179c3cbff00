"""Every built-in method's per-frame features of a run of frames (one shard), as the
feature cache stores them: SPM's training and query vectors (spm_model/spm/features.py),
the baselines' raw vectors and the reference's HOG descriptors."""

from __future__ import annotations

import numpy as np

from spm_model.errors import FeatureError
from spm_model.base.images import raw_vector
from spm_model.methods.descriptors import hog_descriptor, template_descriptor
from spm_model.spm.features import FeatureConfig, manifold_from_keypoints, working_image
from spm_model.spm.keypoints import homography_inliers, sift_keypoints, sift_locations


def path_neighbours(instance_id: np.ndarray, path_index: np.ndarray) -> list[list[int]]:
    """For each frame, the frames of the same instance one path step before and after."""
    where = {(int(i), int(p)): n for n, (i, p) in enumerate(zip(instance_id, path_index))}
    return [[where[k] for k in ((int(i), int(p) - 1), (int(i), int(p) + 1)) if k in where]
            for i, p in zip(instance_id, path_index)]


def frames_features(rgb: np.ndarray, mask: np.ndarray, instance_id: np.ndarray, path_index: np.ndarray,
                    config: FeatureConfig, report=lambda n: None, K: np.ndarray | None = None,
                    path_steps: bool = True, depth: np.ndarray | None = None) -> dict:
    """Features of a run of frames (one shard): rgb (n, H, W, 3) uint8, mask (n, H, W),
    K (n, 3, 3) (for the template descriptors; omitted: none are computed).
    path_steps: whether consecutive path indices are views a 5-degree step apart (a grid
    walk, or an import of a turntable); for randomly sampled views (camera.sampler "sphere"
    or "so3") they are not, so no frame has path neighbours and every training feature
    uses the query rule (train_neighbours 0).

    Returns arrays over the n frames: train_vector / query_vector (n, config.dims)
    float64 (NaN where the frame has too few keypoints), train_eccentricity /
    query_eccentricity (n,), train_keypoints / query_keypoints (n,) int32, raw
    (n, raw_size^2) uint8, train_neighbours (n,) int8 (path neighbours matched;
    0: the training feature used the query rule), with K, template (n, 3535)
    float64 (spm_model/methods/template.py's descriptor), and with depth (n, H, W) metres,
    has_depth (n,) bool: a measured depth under the frame's mask (what N3M needs)."""
    hog = hog_descriptor()
    n = len(rgb)
    neighbours = path_neighbours(instance_id, path_index) if path_steps else [[] for _ in range(n)]
    sift = []
    for i in range(n):  # descriptors only where a path neighbour is matched (neighbours are mutual)
        small, small_mask = working_image(rgb[i], mask[i], config.max_side, config.min_side)
        sift.append(sift_keypoints(small, small_mask) if neighbours[i] else (sift_locations(small, small_mask), None))
    out = {f"{kind}_{name}": np.full((n, config.dims) if name == "vector" else n,
                                     np.nan if name != "keypoints" else 0,
                                     dtype=np.float64 if name != "keypoints" else np.int32)
           for kind in ("train", "query") for name in ("vector", "eccentricity", "keypoints")}
    out["raw"] = np.zeros((n, config.raw_size ** 2), np.uint8)
    out["train_neighbours"] = np.array([len(nb) for nb in neighbours], dtype=np.int8)
    if depth is not None:
        out["has_depth"] = np.array([bool((depth[i][mask[i] > 0] > 0).any()) for i in range(n)])
    if K is not None:
        out["template"] = np.stack([template_descriptor(rgb[i], mask[i] > 0, K[i], hog) for i in range(n)])
    for i in range(n):
        loc, desc = sift[i]
        keep = np.zeros(len(loc), dtype=bool) if neighbours[i] else np.ones(len(loc), dtype=bool)
        for j in neighbours[i]:
            keep |= homography_inliers(loc, desc, *sift[j])
        for kind, points in (("query", loc), ("train", loc[keep])):
            out[f"{kind}_keypoints"][i] = len(points)
            try:
                out[f"{kind}_vector"][i], out[f"{kind}_eccentricity"][i] = manifold_from_keypoints(points, config)
            except FeatureError:
                pass
        out["raw"][i] = raw_vector(rgb[i], mask[i], config.raw_size)
        report(1)
    return out

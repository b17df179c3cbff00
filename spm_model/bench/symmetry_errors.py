"""The paper's rotation criteria up to the object's symmetries.

The paper's ±5° and geodesic errors count a box's half turn as a miss; beside
them the report gives the same criteria against the symmetric equivalent of the
truth nearest the estimate. The symmetries are the ones the spec or the
generator declares (spm_data/core/symmetries.py), the same ones the BOP export
writes: for a rendered instance they come with its mesh (instances.shard_mesh).

For a true rotation R (camera from object), a symmetry S (object frame) gives
the equivalent truth R S. With discrete symmetries every element of the group
is tried. A continuous axis a (object frame) is solved exactly: the rotations
R Rot(a, θ) are all the rotations that take a to R a, and the nearest one to
the estimate R̂ is R̂ Q, Q the smallest rotation taking a to R̂ᵀ R a; its
geodesic error is the angle between R̂ a and R a. Two or more continuous axes
(a sphere) make every rotation equivalent: the error is 0.
The per-angle (±5°) error is read against that nearest equivalent truth.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from spm_data.core.poses import label_to_pose, pose_to_label, wrap_degrees
from spm_model.bench.surface_metrics import rebuilt_mesh


def _smallest_rotation(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(n, 3) unit vectors -> (n, 3, 3): the smallest rotations taking a to b."""
    axis = np.cross(a, b)
    s = np.linalg.norm(axis, axis=1)
    angle = np.arctan2(s, np.einsum("ni,ni->n", a, b))
    safe = np.where(s[:, None] > 1e-12, axis / np.maximum(s, 1e-300)[:, None], 0.0)
    # Opposite vectors: any perpendicular axis (a half turn).
    opposite = (s <= 1e-12) & (angle > 1.0)
    if opposite.any():
        helper = np.where(np.abs(a[opposite, :1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]])
        perp = np.cross(a[opposite], helper)
        safe[opposite] = perp / np.linalg.norm(perp, axis=1, keepdims=True)
    return Rotation.from_rotvec(safe * angle[:, None]).as_matrix()


def nearest_equivalent(pred_R: np.ndarray, true_R: np.ndarray, symmetries) -> np.ndarray:
    """pred_R, true_R (n, 3, 3); symmetries: spm_data.core.symmetries.Symmetries ->
    (n, 3, 3) the rotation equivalent to true_R under the symmetries nearest to pred_R
    (geodesic); true_R itself for an object without symmetry."""
    group = [np.eye(3), *[np.asarray(S, np.float64) for S in symmetries.discrete]]
    axes = [np.asarray(a, np.float64) for a in symmetries.continuous]
    if len(axes) >= 2:
        return pred_R.copy()
    best, best_angle = true_R.copy(), np.full(len(true_R), np.inf)
    for S in group:
        cand = true_R @ S
        if axes:
            a = np.broadcast_to(axes[0], (len(cand), 3))
            target = np.einsum("nji,njk,k->ni", pred_R, cand, axes[0])  # R̂ᵀ (R S) a
            cand = pred_R @ _smallest_rotation(a, target)
        angle = Rotation.from_matrix(np.einsum("nji,njk->nik", pred_R, cand)).magnitude()
        better = angle < best_angle
        best[better], best_angle[better] = cand[better], angle[better]
    return best


def symmetric_errors(pred: np.ndarray, true: np.ndarray, symmetries: list) -> dict:
    """pred, true (n, 6) labels (degrees, metres); symmetries: n Symmetries (None: unknown).
    Returns (n,) ``geodesic_sym`` (degrees) and ``rotation_max_sym`` (largest wrapped
    per-angle error, degrees, against the nearest equivalent truth): NaN where the
    symmetries are unknown, inf for ``rotation_max_sym`` where there is no estimate."""
    n = len(pred)
    geodesic, rot_max = np.full(n, np.nan), np.full(n, np.nan)
    known = np.array([s is not None for s in symmetries], dtype=bool)
    finite = np.isfinite(pred).all(axis=1) & known
    rot_max[known & ~finite] = np.inf
    groups: dict = {}  # frames of each mesh's symmetries (one object per mesh: instance_symmetries)
    for i in np.flatnonzero(finite):
        groups.setdefault(id(symmetries[i]), (symmetries[i], []))[1].append(i)
    for sym, index in groups.values():
        index = np.asarray(index)
        pR, _ = label_to_pose(pred[index])
        tR, tt = label_to_pose(true[index])
        eq = nearest_equivalent(pR, tR, sym)
        geodesic[index] = np.degrees(Rotation.from_matrix(np.einsum("nji,njk->nik", pR, eq)).magnitude())
        eq_label = pose_to_label(eq, tt)
        pred_label = pose_to_label(pR, tt)
        rot_max[index] = np.abs(wrap_degrees(pred_label[:, :3] - eq_label[:, :3])).max(axis=1)
    return {"geodesic_sym": geodesic, "rotation_max_sym": rot_max}


def instance_symmetries(mesh_keys: list) -> list:
    """Per frame, the declared Symmetries of its mesh (None where the mesh is unknown),
    from bench/surface_metrics.mesh_keys; each mesh rebuilt once per process, shared with
    the surface errors (surface_metrics.rebuilt_mesh)."""
    return [None if key is None else rebuilt_mesh(key).symmetries for key in mesh_keys]

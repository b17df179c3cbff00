"""Pose errors measured on the object's surface, where the mesh is known
(rendered shards): ADD and ADD-S (Hinterstoisser et al., ACCV 2012) and the BOP
challenge's MSSD and MSPD (Hodaň et al., ECCV 2020; the BOP 2019 metrics).

For a model with points x (object frame, metres), estimated pose (R̂, t̂),
true pose (R, t) and the model's symmetry transformations S (rotations):
- ADD   = mean_x ||R̂x + t̂ - (Rx + t)||
- ADD-S = mean_x1 min_x2 ||(Rx1 + t) - (R̂x2 + t̂)||  (each true point to the nearest estimated one)
- MSSD  = min_S max_x ||R̂x + t̂ - (RSx + t)||                      (metres)
- MSPD  = min_S max_x ||π(K, R̂x + t̂) - π(K, RSx + t)||           (pixels)
Recall at ADD, ADD-S and ADD(-S) (ADD-S for models with a symmetry, ADD
otherwise) below 10% of the object's diameter; BOP's average recalls AR_MSSD
(thresholds 5%, 10%, ..., 50% of the diameter) and AR_MSPD (5, 10, ..., 50
pixels times width / 640).

Models: ``POINTS`` points sampled uniformly (seeded) on the mesh surface, the
diameter as the largest distance between two mesh vertices. Symmetries are the
ones the spec or the generator declares (spm_data/core/symmetries.py), the same
ones the BOP export writes to models_info.json; a mesh file without declared
symmetries has none (as in BOP). They are combined as bop_toolkit's
get_symmetry_transformations combines them: every discrete one (the identity
included) after every step of a continuous one, the continuous axis sampled in
ceil(π / 0.01) = 315 steps, so no point moves more than 1% of the diameter between
two steps; a ball turned over and turned about its axis is thus its own symmetry.
Two or more continuous axes make every rotation a symmetry (a sphere): MSSD is then
the distance between the centres. A frame whose mesh cannot be rebuilt (imported
data) gets NaN for all four.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from spm_data.core.meshes import diameter
from spm_data.core.symmetries import NO_SYMMETRY

POINTS = 256
CONTINUOUS_STEP = 0.01   # bop_toolkit's max_sym_disc_step: a fraction of the diameter per step
CHUNK = 1 << 21          # points x (frame, symmetry) pairs compared at once (memory bound)
PROBE = 16               # points that rule symmetries out before all are compared (_candidates)
ADD_THRESHOLD = 0.1
MSSD_THRESHOLDS = np.arange(0.05, 0.51, 0.05)
MSPD_THRESHOLDS = np.arange(5.0, 51.0, 5.0)
SURFACE_ERRORS = ("add", "adds", "mssd", "mspd", "diameter", "symmetric", "mspd_scale")


@dataclass(frozen=True)
class ObjectModel:
    """points (P, 3) float64 metres, object frame; diameter metres;
    symmetries (S, 3, 3) float64 rotations, the identity first (symmetry_transforms);
    any_rotation: every rotation is a symmetry (a sphere; ``symmetries`` is then the identity)."""

    points: np.ndarray
    diameter: float
    symmetries: np.ndarray
    any_rotation: bool = False

    @property
    def symmetric(self) -> bool:
        return self.any_rotation or len(self.symmetries) > 1


def symmetry_transforms(symmetries) -> np.ndarray | None:
    """(S, 3, 3) float64 rotations for MSSD and MSPD, the identity first, from a
    spm_data.core.symmetries.Symmetries (module docstring); None when every rotation is
    one (two or more continuous axes)."""
    group = [np.eye(3), *[np.asarray(D, np.float64) for D in symmetries.discrete]]
    axes = [np.asarray(a, np.float64) for a in symmetries.continuous]
    if len(axes) >= 2:
        return None
    if not axes:
        return np.array(group)
    from scipy.spatial.transform import Rotation

    steps = int(np.ceil(np.pi / CONTINUOUS_STEP))
    turns = Rotation.from_rotvec(np.outer(np.arange(steps) * 2.0 * np.pi / steps, axes[0])).as_matrix()
    return np.einsum("kij,gjl->kgil", turns, np.array(group)).reshape(-1, 3, 3)


def object_model(mesh, symmetries=NO_SYMMETRY, seed: int = 0) -> ObjectModel:
    """A trimesh.Trimesh (object frame, metres) and its declared Symmetries -> its ObjectModel."""
    import trimesh

    size = diameter(mesh.vertices)
    points, _ = trimesh.sample.sample_surface(mesh, POINTS, seed=seed)
    transforms = symmetry_transforms(symmetries)
    return ObjectModel(points=np.asarray(points, dtype=np.float64), diameter=size,
                       symmetries=np.eye(3)[None] if transforms is None else transforms,
                       any_rotation=transforms is None)


def _pixels(uvw):
    """(..., 3, P) homogeneous image points -> (..., 2, P) pixels."""
    with np.errstate(divide="ignore", invalid="ignore"):
        return uvw[..., :2, :] / uvw[..., 2:3, :]


def surface_errors(pred_R, pred_t, true_R, true_t, K, model: ObjectModel, width: int) -> dict:
    """Errors of n frames of one object: poses (n, 3, 3) / (n, 3) (metres, OpenCV
    camera), K (n, 3, 3); width: image width in pixels (for MSPD's scale).
    Returns (n,) arrays ``add``, ``adds``, ``mssd`` (metres), ``mspd`` (pixels);
    NaN where the estimate is not finite."""
    from scipy.spatial import cKDTree

    n = len(pred_R)
    out = {k: np.full(n, np.nan) for k in ("add", "adds", "mssd", "mspd")}
    ok = np.isfinite(pred_R).all(axis=(1, 2)) & np.isfinite(pred_t).all(axis=1)
    if not ok.any():
        return out
    x = model.points
    est = np.einsum("nij,pj->npi", pred_R[ok], x) + pred_t[ok][:, None]              # (m, P, 3)
    gt = np.einsum("nij,pj->npi", true_R[ok], x) + true_t[ok][:, None]
    out["add"][ok] = np.linalg.norm(est - gt, axis=2).mean(axis=1)
    # ADD-S in the estimated pose's object frame: the nearest estimated point of each true point.
    local = np.einsum("nji,npj->npi", pred_R[ok], gt - pred_t[ok][:, None])
    out["adds"][ok] = cKDTree(x).query(local.reshape(-1, 3))[0].reshape(local.shape[:2]).mean(axis=1)
    Kok = np.asarray(K, dtype=np.float64)[ok]
    out["mssd"][ok], out["mspd"][ok] = _symmetric_errors(est, true_R[ok], true_t[ok], pred_R[ok], Kok, model)
    return out


def _symmetric_errors(est, true_R, true_t, pred_R, K, model: ObjectModel):
    """MSSD (metres) and MSPD (pixels) of m frames: est (m, P, 3) the estimated points in the
    camera, poses and K (m, ...); the minimum over the model's symmetries, in chunks of
    (frame, symmetry) pairs (m is bounded by the caller: frame_surface_errors' block).
    Points are laid out (..., 3, P) so every transform is one batched matrix product. With many
    symmetries (a continuous axis) most are ruled out first on a few points (_candidates)."""
    x = model.points.T                                                              # (3, P)
    if model.any_rotation:   # the truth turned to the estimate's rotation: only the centres differ
        sym = np.einsum("nji,njk->nik", true_R, pred_R)[:, None]                      # (m, 1, 3, 3)
    else:
        sym = np.broadcast_to(model.symmetries, (len(est),) + model.symmetries.shape)  # (m, S, 3, 3)
    est = est.transpose(0, 2, 1)                                                    # (m, 3, P)
    est_px = _pixels(K @ est)                                                       # (m, 2, P)
    turned = true_R[:, None] @ sym                                                  # (m, S, 3, 3)
    pairs = _candidates(est, est_px, turned, true_t, K, x) if sym.shape[1] > PROBE else None
    if pairs is None:
        pairs = (np.repeat(np.arange(len(est)), sym.shape[1]), np.tile(np.arange(sym.shape[1]), len(est)))
    mssd, mspd = np.full(len(est), np.inf), np.full(len(est), np.inf)
    step = max(1, CHUNK // x.shape[1])
    for lo in range(0, len(pairs[0]), step):
        f, s = pairs[0][lo: lo + step], pairs[1][lo: lo + step]
        sq_3d, sq_px = _squared_shifts(est[f], est_px[f], turned[f, s], true_t[f], K[f], x)
        # sqrt after the max and min: it is monotonic, so the same value as the norms' max-min
        np.minimum.at(mssd, f, sq_3d.max(axis=1))
        np.minimum.at(mspd, f, sq_px.max(axis=1))
    return np.sqrt(mssd), np.sqrt(mspd)


def _squared_shifts(est, est_px, turned, true_t, K, x):
    """Squared 3-D (metres²) and image (pixels²) shifts, (..., Q), between estimated points
    est (..., 3, Q) / est_px (..., 2, Q) and the truth turned by a symmetry: turned (..., 3, 3)
    (true rotation times symmetry), true_t (..., 3), K (..., 3, 3), x (3, Q) model points;
    the leading axes broadcast."""
    gt = turned @ x + true_t[..., :, None]                                          # (..., 3, Q)
    sq_3d = np.square(est - gt).sum(axis=-2)
    sq_px = np.square(est_px - _pixels(K @ gt)).sum(axis=-2)
    return sq_3d, sq_px


def _candidates(est, est_px, turned, true_t, K, x):
    """(frame, symmetry) index pairs, two (k,) int arrays, that can hold each frame's MSSD or
    MSPD minimum. est (m, 3, P) / est_px (m, 2, P): the estimate's points in the camera and
    in pixels; turned (m, S, 3, 3): true rotation times each symmetry; true_t (m, 3) metres;
    K (m, 3, 3); x (3, P) model points.
    A symmetry's largest shift over PROBE of the points is a lower bound of its largest shift
    over all of them; a symmetry whose bound is above the full value of the symmetry with the
    smallest bound cannot be the minimum, and is left out. The bounds are one matrix product
    each (K folded into the rotation), so they round a little differently from the full
    values: the margin keeps every symmetry within 1e-6 (relative) or 1e-12 (m², px²) of the
    full value, far above that rounding, so the minimum is kept."""
    m, S = turned.shape[:2]
    every = max(1, x.shape[1] // PROBE)
    probe = x[:, ::every][:, :PROBE]                                                # (3, Q)

    def moved(rotation, shift):   # rotation (m, S, 3, 3) @ probe + shift (m, 3), one product
        return (rotation.reshape(-1, 3) @ probe).reshape(m, S, 3, -1) + shift[:, None, :, None]

    low_3d = np.square(est[:, None, :, ::every][..., :PROBE] - moved(turned, true_t)).sum(axis=2)
    uvw = moved(K[:, None] @ turned, np.einsum("mij,mj->mi", K, true_t))
    low_px = np.square(est_px[:, None, :, ::every][..., :PROBE] - _pixels(uvw)).sum(axis=2)
    keep = np.zeros((m, S), bool)
    for which, low in enumerate((low_3d.max(axis=2), low_px.max(axis=2))):
        best = low.argmin(axis=1)
        full = _squared_shifts(est, est_px, turned[np.arange(m), best], true_t, K, x)[which].max(axis=1)
        keep |= low <= full[:, None] * (1 + 1e-6) + 1e-12
        keep[np.arange(m), best] = True
    return np.nonzero(keep)


def _recall(errors, thresholds) -> float | None:
    """% of frames under each threshold (a NaN error, no estimate, is a miss), averaged."""
    if len(errors) == 0:
        return None
    e = np.where(np.isfinite(errors), errors, np.inf)
    return float(np.mean([(e < th).mean() for th in np.atleast_1d(thresholds)]) * 100.0)


def summarise_surface(errors: dict) -> dict | None:
    """Recalls and medians over the frames whose model is known (``diameter``
    finite); None when there are none. Keys: frames, add_recall, adds_recall,
    add_s_recall (ADD(-S)), ar_mssd, ar_mspd, add_median_mm, adds_median_mm,
    mssd_median_mm, mspd_median_px."""
    known = np.isfinite(errors["diameter"])
    if not known.any():
        return None
    e = {k: np.asarray(errors[k])[known] for k in SURFACE_ERRORS}
    rel = {k: e[k] / e["diameter"] for k in ("add", "adds", "mssd")}
    add_s = np.where(e["symmetric"] > 0, rel["adds"], rel["add"])

    def median(values, scale):
        values = values[np.isfinite(values)]
        return float(np.median(values)) * scale if len(values) else None

    return {"frames": int(known.sum()),
            "add_recall": _recall(rel["add"], ADD_THRESHOLD), "adds_recall": _recall(rel["adds"], ADD_THRESHOLD),
            "add_s_recall": _recall(add_s, ADD_THRESHOLD),
            "ar_mssd": _recall(rel["mssd"], MSSD_THRESHOLDS),
            "ar_mspd": _recall(e["mspd"] / e["mspd_scale"], MSPD_THRESHOLDS),
            "add_median_mm": median(e["add"], 1000.0), "adds_median_mm": median(e["adds"], 1000.0),
            "mssd_median_mm": median(e["mssd"], 1000.0), "mspd_median_px": median(e["mspd"], 1.0)}


def _mesh_key(attrs: dict, instance_id: int):
    from spm_data.core.instances import MESH_ATTRS

    if attrs.get("source") != "synthetic" or not attrs.get("spec"):
        return None
    return tuple((k, attrs[k]) for k in MESH_ATTRS if k in attrs), int(instance_id)


_MODELS: dict = {}
_MESHES: dict = {}


def rebuilt_mesh(key):
    """The TexturedMesh of a rendered instance (a :func:`mesh_keys` key), rebuilt from its
    spec once per process: the surface errors and the symmetry-aware errors share it."""
    if key not in _MESHES:
        from spm_data.core.instances import shard_mesh

        _MESHES[key] = shard_mesh(dict(key[0]), key[1])
    return _MESHES[key]


def _model(key) -> ObjectModel:
    """The ObjectModel of a rendered instance, rebuilt from its spec (cached per process)."""
    if key not in _MODELS:
        mesh = rebuilt_mesh(key)
        _MODELS[key] = object_model(mesh.to_trimesh(), mesh.symmetries)
    return _MODELS[key]


def frame_surface_errors(pred: np.ndarray, true: np.ndarray, K: np.ndarray, width: np.ndarray,
                         mesh_keys: list, block: int = 128) -> dict:
    """Surface errors of n frames: pred, true (n, 6) labels; K (n, 3, 3); width (n,)
    pixels; mesh_keys: n hashable keys (None: mesh unknown) from :func:`mesh_keys`.
    Returns (n,) arrays ``add``, ``adds``, ``mssd`` (metres), ``mspd`` (pixels),
    ``diameter`` (metres), ``symmetric`` (1 when the model has a symmetry),
    ``mspd_scale`` (width / 640); NaN where the mesh is unknown."""
    from spm_data.core.poses import label_to_pose

    n = len(pred)
    out = {k: np.full(n, np.nan) for k in SURFACE_ERRORS}
    finite = np.isfinite(pred).all(axis=1)
    safe = np.where(finite[:, None], pred, 0.0)
    pR, pt = label_to_pose(safe)
    pR[~finite], pt[~finite] = np.nan, np.nan
    tR, tt = label_to_pose(true)
    groups: dict = {}
    for i, key in enumerate(mesh_keys):  # one pass: frames of each mesh
        if key is not None:
            groups.setdefault(key, []).append(i)
    for key, index in groups.items():
        model = _model(key)
        index = np.asarray(index)
        for start in range(0, len(index), block):
            sel = index[start: start + block]
            errors = surface_errors(pR[sel], pt[sel], tR[sel], tt[sel], K[sel], model, int(width[sel[0]]))
            for k, v in errors.items():
                out[k][sel] = v
            out["diameter"][sel] = model.diameter
            out["symmetric"][sel] = float(model.symmetric)
            out["mspd_scale"][sel] = width[sel] / 640.0
    return out


def mesh_keys(shards: np.ndarray, instance_ids: np.ndarray) -> list:
    """Per frame, the key of the mesh it was rendered from, or None (not rendered by spm)."""
    from spm_data.io.shards import read_attrs

    attrs = {s: read_attrs(s) for s in set(shards.tolist())}
    return [_mesh_key(attrs[s], i) for s, i in zip(shards.tolist(), instance_ids.tolist())]

"""BOP object models from our meshes: ``models/``, ``models_eval/`` and ``models_info.json``.

* ``models/obj_NNNNNN.ply``: the render mesh in millimetres, object frame, with
  unit vertex normals, vertex colours (the texture sampled at each vertex, for
  renderers that ignore textures) and texture coordinates, its texture beside it
  as ``obj_NNNNNN.png`` (``comment TextureFile``), as BOP's textured models are.
* ``models_eval/obj_NNNNNN.ply``: the same surface resampled so its vertices
  spread evenly over it, the point set BOP's errors (ADD, MSSD, MSPD) average or
  maximise over. BOP resamples with MeshLab (uniform resampling, then
  decimation); we subdivide until no edge is longer than half a cell, then keep
  one vertex per occupied cell of a grid of ``EVAL_CELL_FRACTION`` of the
  diameter (about 5 mm on a 250 mm object): the surface point nearest the
  mean of the cell's points (vertex clustering, without MeshLab); and, without
  faces, the render mesh's extreme vertices (lowest and highest along each axis,
  both ends of its diameter), so the resampled surface keeps the model's extent.
* ``models_info.json`` (:func:`save_models_info`): ``diameter`` (largest distance
  between two vertices), ``min_x`` ... ``size_z`` (bounding box), recomputed in
  each folder from its PLYs as bop_toolkit's ``scripts/calc_model_info.py``
  computes them (float32 vertices, its diameter's arithmetic); with the extreme
  vertices kept, ``models/`` and ``models_eval/`` get the same numbers. Then the
  shape's ``symmetries_discrete`` (4 x 4 row-major matrices, translation in mm)
  and ``symmetries_continuous`` (``axis``, ``offset`` in mm), omitted when none.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np

from spm_data.errors import SpmError
from spm_data.core.meshes import TexturedMesh
from spm_data.core.raster import MM_PER_M
from spm_data.core.symmetries import NO_SYMMETRY, Symmetries
from spm_data.formats.ply import load_ply, save_ply

EVAL_CELL_FRACTION = 0.02  # models_eval: one vertex per cell of 2 % of the diameter


def texture_colors(texture: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """(V, 3) uint8: ``texture`` (H, W, 3) uint8 at ``uv`` (V, 2) (v = 0 at the bottom row), nearest pixel."""
    h, w = texture.shape[:2]
    col = np.clip(np.rint(uv[:, 0] * (w - 1)), 0, w - 1).astype(np.int64)
    row = np.clip(np.rint((1.0 - uv[:, 1]) * (h - 1)), 0, h - 1).astype(np.int64)
    return texture[row, col]


def _row_keys(rows: np.ndarray) -> np.ndarray:
    """(N,) int64 keys of (N, 3) int64 rows, in the rows' lexicographic order (equal rows, equal
    keys): np.unique on them is np.unique(rows, axis=0), several times faster."""
    low = rows.min(axis=0)
    span = rows.max(axis=0) - low + 1
    if float(np.prod(span.astype(np.float64))) >= 2.0 ** 62:   # keys would overflow: rank rows instead
        return np.unique(rows, axis=0, return_inverse=True)[1].ravel()
    return np.ravel_multi_index((rows - low).T, span)


def eval_resample(vertices: np.ndarray, faces: np.ndarray, cell: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(vertices (V', 3), faces (F', 3), unit normals (V', 3)): the surface with one vertex
    per occupied ``cell`` (same units as ``vertices``), the surface point nearest the mean there.
    Faces that collapse are dropped; their vertices stay (a rod thinner than a cell is
    still surface to measure), with the mean normal of the surface they stand for."""
    import trimesh

    merged = trimesh.Trimesh(vertices, faces, process=True)  # per-corner copies -> shared vertices
    v, f = trimesh.remesh.subdivide_to_size(merged.vertices, merged.faces, max_edge=cell / 2.0)
    fine_normals = np.asarray(trimesh.Trimesh(v, f, process=False).vertex_normals)
    _, cluster = np.unique(_row_keys(np.floor(v / cell).astype(np.int64)), return_inverse=True)
    n = int(cluster.max()) + 1
    centres, normals = np.zeros((n, 3)), np.zeros((n, 3))
    np.add.at(centres, cluster, v)
    np.add.at(normals, cluster, fine_normals)
    centres /= np.bincount(cluster, minlength=n)[:, None]
    # Each cell keeps its surface point nearest the cell's mean: the mean itself cuts corners.
    order = np.lexsort((np.linalg.norm(v - centres[cluster], axis=1), cluster))
    nearest = order[np.flatnonzero(np.r_[True, np.diff(cluster[order]) != 0])]
    length = np.linalg.norm(normals, axis=1, keepdims=True)
    normals = np.where(length > 1e-6, normals / np.maximum(length, 1e-12), fine_normals[nearest])  # sides cancel
    f = cluster[f]
    f = f[(f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])]
    _, first = np.unique(_row_keys(np.sort(f, axis=1)), return_index=True)  # duplicates out, winding kept
    return v[nearest], f[np.sort(first)], normals


_RESAMPLED: dict = {}   # content digest -> eval_resample's arrays (read-only), this process
_RESAMPLED_MAX = 64


def _remembered_resample(vertices: np.ndarray, faces: np.ndarray, cell: float) -> tuple:
    """eval_resample, remembered per process by the mesh's content: exports that share objects
    (several splits or folders of one dataset) resample each object once (0.2-1 s each)."""
    digest = hashlib.sha256(repr((np.shape(vertices), np.shape(faces), float(cell))).encode())
    for a in (np.ascontiguousarray(vertices, np.float64), np.ascontiguousarray(faces, np.int64)):
        digest.update(a.tobytes())
    key = digest.hexdigest()
    if key not in _RESAMPLED:
        if len(_RESAMPLED) >= _RESAMPLED_MAX:
            _RESAMPLED.pop(next(iter(_RESAMPLED)))   # the oldest
        arrays = eval_resample(vertices, faces, cell)
        for a in arrays:
            a.setflags(write=False)
        _RESAMPLED[key] = arrays
    return _RESAMPLED[key]


def symmetry_info(symmetries: Symmetries) -> dict:
    """The models_info.json symmetry keys (rotations about the object origin: zero offset)."""
    info = {}
    if symmetries.discrete:
        mats = []
        for R in symmetries.discrete:
            M = np.eye(4)
            M[:3, :3] = R
            mats.append([round(float(x), 12) + 0.0 for x in M.ravel()])
        info["symmetries_discrete"] = mats
    if symmetries.continuous:
        info["symmetries_continuous"] = [{"axis": [float(a) for a in axis], "offset": [0.0, 0.0, 0.0]}
                                         for axis in symmetries.continuous]
    return info


def ply_vertices(mesh: TexturedMesh) -> np.ndarray:
    """(V, 3) float32: ``mesh``'s vertices in mm, the values its PLY stores (and BOP's tools read)."""
    return np.asarray(mesh.vertices * MM_PER_M, dtype=np.float32)


_DIAMETER_ENDS: dict = {}   # sha1 of the points -> diameter_ends: models/ and models_eval/ share them


def diameter_ends(points: np.ndarray) -> tuple[float, int, int]:
    """diameter_ends_of, remembered per process by the points' bytes (an export computes each
    model's several times: its info, its eval surface's ends, and each models_info.json)."""
    pts = np.ascontiguousarray(points, dtype=np.float64)
    key = hashlib.sha1(pts.tobytes()).hexdigest()
    if key not in _DIAMETER_ENDS:
        if len(_DIAMETER_ENDS) >= 4096:
            _DIAMETER_ENDS.pop(next(iter(_DIAMETER_ENDS)))
        _DIAMETER_ENDS[key] = diameter_ends_of(pts)
    return _DIAMETER_ENDS[key]


def diameter_ends_of(points: np.ndarray) -> tuple[float, int, int]:
    """(diameter, i, j): the largest distance between two of ``points`` (N, 3) and the indices of
    two points that far apart, by misc.calc_pts_diameter's arithmetic (float64, ((dx² + dy²) +
    dz²), square root). Only points that can be an end are compared: p is one only if
    |p - c| >= D - max|q - c|, for any centre c and any distance D between two points."""
    pts = np.asarray(points, dtype=np.float64)
    if len(pts) < 2:
        return 0.0, 0, 0
    radius = np.linalg.norm(pts - (pts.min(axis=0) + pts.max(axis=0)) / 2, axis=1)
    far = pts[int(np.argmax(radius))]
    bound = float(np.sqrt(((pts - far) ** 2).sum(axis=1).max()))
    ends = np.flatnonzero(radius >= bound - radius.max() - 1e-6 * (1.0 + bound))
    best, pair = -1.0, (0, 0)
    for start in range(0, len(ends), 1024):   # blocks of 1024 rows: bounded memory
        d = pts[ends[start:start + 1024], None, :] - pts[None, ends, :]
        sq = (d[..., 0] * d[..., 0] + d[..., 1] * d[..., 1]) + d[..., 2] * d[..., 2]
        k = int(np.argmax(sq))
        if sq.flat[k] > best:
            best, pair = float(sq.flat[k]), (int(ends[start + k // len(ends)]), int(ends[k % len(ends)]))
    return float(np.sqrt(best)), pair[0], pair[1]


def extreme_vertices(points: np.ndarray) -> np.ndarray:
    """Indices (sorted, unique) of the vertices of ``points`` (N, 3) that fix its models_info
    numbers: the lowest and highest along each axis, and the two ends of its diameter."""
    pts = np.asarray(points, dtype=np.float64)
    _, i, j = diameter_ends(pts)
    return np.unique(np.concatenate([pts.argmin(axis=0), pts.argmax(axis=0), [i, j]]))


def model_info(vertices_mm: np.ndarray, symmetries: Symmetries) -> dict:
    """A models_info.json entry for a PLY whose vertices are ``vertices_mm`` (V, 3) (rounded to
    float32 here, as the PLY stores them): calc_model_info's numbers, and the symmetry keys."""
    pts = np.asarray(vertices_mm, dtype=np.float32).astype(np.float64)
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    info = {"diameter": diameter_ends(pts)[0], "min_x": float(lo[0]), "min_y": float(lo[1]),
            "min_z": float(lo[2]), "size_x": float(hi[0] - lo[0]), "size_y": float(hi[1] - lo[1]),
            "size_z": float(hi[2] - lo[2])}
    return {**info, **symmetry_info(symmetries)}


def _eval_surface(mesh: TexturedMesh, diameter_mm: float, unit: TexturedMesh | None, size: float) -> tuple:
    """models_eval's resampled surface (mm) of ``mesh``; for a mesh that is ``unit`` scaled by
    ``size`` (a distractor drawn at its own size), ``unit``'s resampling scaled: the same surface
    points relative to the diameter, resampled once per pool mesh instead of once per size."""
    if unit is None:
        return _remembered_resample(mesh.vertices * MM_PER_M, mesh.faces, EVAL_CELL_FRACTION * diameter_mm)
    # diameter_mm / size is the unit mesh's diameter up to float32 rounding (the PLY's vertices),
    # which differs in the last digits from size to size: 6 significant digits make it one cell,
    # and one resampling, per pool mesh.
    cell = float(f"{EVAL_CELL_FRACTION * diameter_mm / size:.6g}")
    v, f, n = _remembered_resample(unit.vertices * MM_PER_M, unit.faces, cell)
    return v * size, f, n


def save_bop_model(root: Path, obj_id: int, mesh: TexturedMesh, unit: TexturedMesh | None = None,
                   size: float = 1.0) -> dict:
    """Write ``mesh`` as object ``obj_id`` under ``root`` (models/, models_eval/); returns its
    models_info.json entry. ``unit``, ``size``: ``mesh`` is ``unit`` scaled by ``size`` (_eval_surface)."""
    import cv2

    name = f"obj_{obj_id:06d}"
    vertices = ply_vertices(mesh)
    texture_name = f"{name}.png"
    ok, png = cv2.imencode(".png", cv2.cvtColor(mesh.texture, cv2.COLOR_RGB2BGR))
    if not ok:
        raise SpmError(f"could not encode the texture of {mesh.name} as PNG")
    (root / "models" / texture_name).write_bytes(png.tobytes())
    save_ply(root / "models" / f"{name}.ply", vertices, mesh.faces, normals=mesh.normals,
             colors=texture_colors(mesh.texture, mesh.uv), uv=mesh.uv, texture_file=texture_name)
    info = model_info(vertices, mesh.symmetries)
    v_eval, f_eval, n_eval = _eval_surface(mesh, _unit_diameter(unit) * size if unit is not None
                                           else info["diameter"], unit, size)
    # The resampled surface keeps the model's extreme vertices (faceless), so calc_model_info finds
    # the same box and diameter in models_eval/ as in models/: BOP's error thresholds (fractions
    # of the diameter) do not shrink with the resampling.
    ends = extreme_vertices(vertices)
    save_ply(root / "models_eval" / f"{name}.ply", np.concatenate([v_eval, mesh.vertices[ends] * MM_PER_M]),
             f_eval, normals=np.concatenate([n_eval, mesh.normals[ends]]))
    return info


_DIAMETERS: dict = {}   # id(unit mesh) -> (mesh, its diameter in mm): pool meshes live for the process


def _unit_diameter(unit: TexturedMesh) -> float:
    """Diameter (mm) of a pool mesh, once per mesh: the cell of every size of it follows from it,
    so one resampling serves them all."""
    if id(unit) not in _DIAMETERS:
        _DIAMETERS[id(unit)] = (unit, model_info(unit.vertices * MM_PER_M, NO_SYMMETRY)["diameter"])
    return _DIAMETERS[id(unit)][1]


def save_models_info(path: Path, info: dict) -> None:
    """Write ``info`` (obj_id -> entry) as ``path`` (models_info.json); each object's diameter and
    box are recomputed from its ``obj_NNNNNN.ply`` beside ``path`` when there is one, so every
    folder's file has its own models' numbers (models_eval/: the resampled surface's)."""
    out = {}
    for obj_id, entry in info.items():
        ply = Path(path).parent / f"obj_{int(obj_id):06d}.ply"
        geometry = model_info(load_ply(ply)["vertices"], NO_SYMMETRY) if ply.is_file() else {}
        out[str(obj_id)] = {**entry, **geometry}
    Path(path).write_text(json.dumps(out, indent=1))


def load_models_info(path) -> dict:
    """models_info.json: obj_id (int) -> entry; SpmError naming the file if unreadable."""
    try:
        payload = json.loads(Path(path).read_text())
        return {int(k): v for k, v in payload.items()}
    except (OSError, ValueError, AttributeError) as exc:
        raise SpmError(f"{path}: unreadable models_info.json ({exc})") from None

"""3-D distractors at an exact visible fraction: the spec's ``[distractors]`` table.

Per frame a target visible fraction ``v`` is drawn from ``visible``; ``count``
distractors, each a built-in class instance or a mesh file, randomly turned,
are placed between the camera and the target (wholly nearer than the target's
nearest point), so that what they hide of the target's silhouette adds up to
``1 - v`` of it. Distractor ``k`` covers a share of that, and slides across the
image plane at its depth until the covered pixel count is its cumulative share:
a bracketing root search on the slide, with silhouettes rasterised in numpy
(spm_data.core.raster) at the pixel centres the renderers sample. The poses are
the same for every renderer; the render's instance ids then give the visible
mask, whose fraction lands within a pixel or two of the draw.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from spm_data.errors import SpecError, SpmError
from spm_data.core.mesh_files import load_mesh_file
from spm_data.core.shapes import CLASSES, procedural_mesh
from spm_data.core.randomize import frame_stream
from spm_data.core.raster import CLIP_NEAR, silhouette

DISTRACTOR_INSTANCE0 = 10_000  # procedural instances from here, so no distractor repeats a target instance
_GROWTH = 1.3                  # a distractor too small for its share grows by this, up to _MAX_RADIUS
_MAX_RADIUS = 0.85             # its bounding radius over its depth: it stays in front of the camera
_MAX_STEPS = 30                # root-search steps per distractor
_TOLERANCE = 0.004             # of the target's pixels: close enough to a distractor's share


@dataclass(frozen=True)
class DistractorSpec:
    """``[distractors]``: ``count`` objects a frame hiding ``1 - v`` of the target,
    ``v`` uniform in ``visible``."""

    count: int = 0
    visible: tuple[float, ...] = (0.4, 0.9)   # the target's visible fraction, [min, max]
    classes: tuple[str, ...] = ()             # built-in classes; default: all, when no files are given
    files: tuple[str, ...] = ()               # mesh globs, relative to the spec file
    instances: int = 8                        # instances of each built-in class to draw from
    scale: tuple[float, ...] = (0.6, 1.2)     # a distractor's image size over the target's, [min, max]
    depth: tuple[float, ...] = (0.4, 0.7)     # its depth over the target's nearest point's, [min, max]


@dataclass(frozen=True, eq=False)
class PlacedDistractor:
    """One distractor in a frame: pool index ``mesh_index`` (distractor_pool),
    ``mesh`` a TexturedMesh of longest side 1 (object frame), scaled by ``size``
    metres, then ``R`` (3, 3) and ``t`` (3,) map it to the camera (OpenCV)."""

    mesh_index: int
    mesh: object
    size: float
    R: np.ndarray
    t: np.ndarray

    def matrix(self) -> np.ndarray:
        """(4, 4) float64 object -> camera (OpenCV), the scale included."""
        M = np.eye(4)
        M[:3, :3] = self.R * self.size
        M[:3, 3] = self.t
        return M


@dataclass(frozen=True, eq=False)
class Placement:
    """A frame's distractors; ``amodal`` (H, W) bool, the target's silhouette with
    nothing in front; ``visible_target`` the drawn fraction; ``visible`` the
    fraction the placed silhouettes leave (1.0 when the target is out of view)."""

    distractors: tuple
    amodal: np.ndarray
    visible_target: float
    visible: float


def pool_names(spec) -> list[str]:
    """The distractor meshes a spec draws from, as names: ``box-10003``, or a file's path."""
    return list(_pool_names_in(spec, spec.base_dir))


@lru_cache(maxsize=8)
def _pool_names_in(spec, base_dir: str) -> tuple:  # globbed once per spec and folder (specs compare without it)
    d = spec.distractors
    names = [f"{c}-{DISTRACTOR_INSTANCE0 + i}" for c in _classes(d) for i in range(d.instances)]
    return tuple(names + [str(p) for p in _files(base_dir, d.files)])


def _classes(d: DistractorSpec) -> tuple:
    return d.classes or (() if d.files else CLASSES)


def _files(base_dir: str, patterns: tuple) -> list[Path]:
    out = []
    for pattern in patterns:
        found = sorted(Path(base_dir).glob(pattern))
        if not found:
            raise SpecError(f"distractors.files: {pattern!r} matches no file in {base_dir}")
        out += found
    return out


def pool_mesh(spec, index: int):
    """Mesh ``index`` of the spec's pool (pool_names), longest side 1 metre. The pool is
    built once and kept (renderers keep each mesh's scene objects by identity, so a
    mesh made twice would be built twice): keep it to what fits in memory."""
    return _pool_mesh(spec, spec.base_dir, index)


@lru_cache(maxsize=None)
def _pool_mesh(spec, base_dir: str, index: int):
    name = _pool_names_in(spec, base_dir)[index]
    if index < len(_classes(spec.distractors)) * spec.distractors.instances:
        cls, inst = name.rsplit("-", 1)
        return procedural_mesh(cls, int(inst), seed=spec.seed, size=1.0)
    return load_mesh_file(name, size=1.0, seed=spec.seed)


def place_distractors(spec, mesh, R, t, K, instance: int, path_index: int) -> Placement:
    """Place the frame's distractors in front of ``mesh`` (the target, posed by
    ``R`` (3, 3), ``t`` (3,), seen through ``K`` (3, 3)); deterministic per frame."""
    d, h, w = spec.distractors, spec.image.height, spec.image.width
    rng = frame_stream(spec, instance, path_index, "distractors")
    v = float(rng.uniform(d.visible[0], d.visible[1]))
    z_near = float(np.min(np.asarray(mesh.vertices) @ np.asarray(R)[2] + t[2]))
    if z_near < 2 * CLIP_NEAR:
        raise SpmError(f"frame {instance}/{path_index}: the target comes within {z_near * 100:.1f} cm of the camera, "
                       "too near for distractors in front of it; use larger camera distances or a smaller mesh.size")
    amodal = silhouette(mesh.vertices, mesh.faces, K, R, t, h, w)
    area = int(amodal.sum())
    if area == 0 or d.count == 0:
        return Placement((), amodal, v, 1.0)
    weights = rng.uniform(0.5, 1.5, d.count)
    shares = np.round((1.0 - v) * area * np.cumsum(weights) / weights.sum()).astype(int)
    window = _Window(amodal, K)
    covered = np.zeros_like(window.target)
    placed = []
    for k in range(d.count):
        one, covered = _place_one(spec, rng, window, covered, int(shares[k]), z_near)
        placed.append(one)
    visible = 1.0 - float((covered & window.target).sum()) / area
    return Placement(tuple(placed), amodal, v, visible)


class _Window:
    """The target's bounding box: silhouettes are only rasterised where they can hide it."""

    def __init__(self, amodal, K):
        ys, xs = np.nonzero(amodal)
        self.y0, self.x0 = int(ys.min()), int(xs.min())
        self.target = amodal[self.y0:ys.max() + 1, self.x0:xs.max() + 1]
        self.K = np.array(K, dtype=np.float64)
        self.K_window = self.K.copy()
        self.K_window[:2, 2] -= (self.x0, self.y0)
        self.centre = np.array([xs.mean(), ys.mean()])
        self.extent = float(max(np.ptp(xs), np.ptp(ys)) + 1)
        self.radius = float(np.max(np.hypot(xs - self.centre[0], ys - self.centre[1]))) + 1.0

    def covered(self, mesh, size, R, t) -> np.ndarray:
        hh, ww = self.target.shape
        return silhouette(np.asarray(mesh.vertices) * size, mesh.faces, self.K_window, R, t, hh, ww) & self.target


def _place_one(spec, rng, window, covered, share, z_near):
    """One distractor whose silhouette brings ``covered`` (window bool) to ``share`` pixels."""
    d = spec.distractors
    index = int(rng.integers(len(_pool_names_in(spec, spec.base_dir))))
    mesh = pool_mesh(spec, index)
    R = Rotation.from_quat(rng.normal(size=4)).as_matrix()
    scale, depth = rng.uniform(*d.scale), rng.uniform(*d.depth)
    direction = rng.uniform(0.0, 2 * np.pi)
    unit_radius = float(np.max(np.linalg.norm(mesh.vertices, axis=1)))
    fx, K_inv = window.K[0, 0], np.linalg.inv(window.K)
    before = int(covered.sum())
    a_per_scale = window.extent / fx * unit_radius  # the distractor's radius over its depth, per unit of scale
    # Its radius is a * z: between the camera's clip plane and the target, z (1 - a) >= 2 CLIP_NEAR
    # and z (1 + a) <= 0.95 z_near, so a <= (0.95 z_near - 2 CLIP_NEAR) / (0.95 z_near + 2 CLIP_NEAR).
    room = (0.95 * z_near - 2 * CLIP_NEAR) / (0.95 * z_near + 2 * CLIP_NEAR)
    max_scale = min(_MAX_RADIUS, room) / a_per_scale
    scale = min(scale, max_scale)
    while True:
        a = scale * a_per_scale
        z = min(max(depth * z_near, 2 * CLIP_NEAR / (1.0 - a)), 0.95 * z_near / (1.0 + a))
        size = scale * window.extent * z / fx
        # Pixels from the target's centre to clear it: twice the distractor's on-axis image radius,
        # as off the axis (or with a shifted principal point) perspective stretches it.
        reach = window.radius + 2.0 * fx * a / (1.0 - a) + 2.0

        def at(s, size=size, z=z, reach=reach, seen={}):  # noqa: B006 - seen: this size's slides, memoised
            if s not in seen:
                p = window.centre + s * reach * np.array([np.cos(direction), np.sin(direction)])
                t = z * (K_inv @ np.array([p[0], p[1], 1.0]))
                seen[s] = (t, covered | window.covered(mesh, size, R, t))
            return seen[s]

        grown = min(scale * _GROWTH, max_scale)
        if share <= before or int(at(0.0)[1].sum()) >= share or grown <= scale * 1.001:
            break  # big enough to cover its share, or as big as it may be (then centred: the best it does)
        scale = grown
    s = _solve(lambda s: int(at(s)[1].sum()) - share, max(1, int(_TOLERANCE * window.target.sum())))
    t, covered = at(s)
    return PlacedDistractor(index, mesh, float(size), R, t), covered


def _solve(g, tol: int) -> float:
    """A slide ``s`` in [0, 1] with ``|g(s)|`` the smallest found, for ``g(0) >= 0 >= g(1)``:
    Illinois false position (g counts pixels, so it jumps; the halving keeps it moving)."""
    lo, hi, g_lo, g_hi = 0.0, 1.0, g(0.0), g(1.0)
    best = min((abs(g_lo), 0.0), (abs(g_hi), 1.0))
    last = 0
    for _ in range(_MAX_STEPS):
        if best[0] <= tol or g_lo < 0 or g_hi > 0 or g_lo == g_hi:
            break
        s = (lo * g_hi - hi * g_lo) / (g_hi - g_lo)
        if not lo < s < hi:
            s = 0.5 * (lo + hi)
        value = g(s)
        best = min(best, (abs(value), s))
        if value >= 0:
            lo, g_lo = s, value
            g_hi = g_hi / 2 if last == 1 else g_hi
            last = 1
        else:
            hi, g_hi = s, value
            g_lo = g_lo / 2 if last == -1 else g_lo
            last = -1
    return best[1]


def validate_distractors(d: DistractorSpec, base_dir: str) -> None:
    """SpecError naming the ``distractors.`` key for any bad value."""
    if d.count < 0 or d.count > 16:
        raise SpecError(f"distractors.count: expected 0..16, got {d.count}")
    for key, lo, hi in (("visible", 0.0, 1.0), ("scale", 0.05, 10.0), ("depth", 0.05, 0.95)):
        values = getattr(d, key)
        if len(values) != 2 or values[0] > values[1] or values[0] < lo or values[1] > hi:
            raise SpecError(f"distractors.{key}: expected [min, max] within [{lo:g}, {hi:g}], got {list(values)}")
    for c in d.classes:
        if c not in CLASSES:
            raise SpecError(f"distractors.classes: {c!r} is not a built-in class ({', '.join(CLASSES)})")
    if d.instances < 1:
        raise SpecError(f"distractors.instances: expected an integer >= 1, got {d.instances}")
    if d.count:
        _files(base_dir, d.files)

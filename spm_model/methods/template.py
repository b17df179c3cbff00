"""The reference estimator: HOG templates of the object's box, matched by
nearest neighbour (a template matcher in the spirit of LINEMOD and of
Murase & Nayar's appearance manifolds; Dalal & Triggs' HOG from OpenCV).

Per frame, the object's box (from the mask; the region of interest when there
is no mask) is cut out as a square around the box centre with 5% margin, the
grey image masked to the object, resized to 64 x 64, and described by HOG
(16-pixel blocks, 8-pixel cells, 18 signed-gradient bins: 3,528 values). Training keeps the
unit-normalised descriptors projected on their top ``components`` principal
axes, with each template's pose and box geometry. A query takes its nearest
template's pose, mapped to the query's box:

- rotation: the template's rotation; with ``ray_correction``, turned by the
  rotation that takes the template's viewing ray to the query's (an object
  seen off the optical axis keeps its appearance: the allocentric
  correction). It is off by default: every frame spm renders looks at the
  object, where the correction only adds the sub-degree noise of the
  estimated centre (enough to fail the ±5° tolerance on a 5° grid);
- distance: the median distance of the ``size_neighbours`` training frames
  whose apparent size (the box's longer side over the focal length, in log)
  is closest: size in the image is inverse to distance, and objects are
  normalised to one size, so this transfers between classes;
- position: the template's offset from box centre to object centre, scaled
  to the query's box, back-projected through the query's K to that distance.

Input: frames as in spm_model/base/frames.py (rgb, mask, K); output (n, 6) labels.
"""

from __future__ import annotations

import numpy as np

from spm_data.core.poses import label_to_pose, pose_to_label
from spm_model.methods.descriptors import GEOMETRY, HOG_SIZE, hog_descriptor, template_descriptor
from spm_model.base.estimator import PoseEstimator, check_fitted
from spm_model.base.frames import column
from spm_model.base.model_files import check_xy, load_model_file, need, need_finite, save_model_file

def frame_descriptors(frames) -> np.ndarray:
    """(n, HOG_SIZE + 7) descriptors of a frame sequence (cached column ``template`` when present)."""
    hog = hog_descriptor()
    return column(frames, "template", lambda f: template_descriptor(f["rgb"], f["mask"], f["K"], hog))


def _rotation_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(n, 3) unit vectors -> (n, 3, 3) the smallest rotations taking a to b (Rodrigues)."""
    v = np.cross(a, b)
    c = np.einsum("ni,ni->n", a, b)
    vx = np.zeros((len(a), 3, 3))
    vx[:, 0, 1], vx[:, 0, 2], vx[:, 1, 2] = -v[:, 2], v[:, 1], -v[:, 0]
    vx = vx - vx.transpose(0, 2, 1)
    return np.eye(3) + vx + vx @ vx / (1 + np.maximum(c, -1 + 1e-12))[:, None, None]


def _rays(K: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """K (n, 3, 3), uv (n, 2) pixels -> (n, 3) unit viewing rays (camera frame)."""
    h = np.concatenate([uv, np.ones((len(uv), 1))], axis=1)
    r = np.linalg.solve(K, h[:, :, None])[:, :, 0]
    return r / np.linalg.norm(r, axis=1, keepdims=True)


def _top_eigh(sym: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """The k largest eigenpairs of a symmetric (s, s) matrix, largest first: (k,), (s, k).
    Only those are computed (LAPACK's MRRR, dsyevr, on an index range): the same pairs as a
    full eigendecomposition to rounding, without the s - k others nobody uses."""
    from scipy.linalg import eigh

    s = len(sym)
    values, vectors = eigh(sym, subset_by_index=[s - k, s - 1], driver="evr", check_finite=False)
    return values[::-1], vectors[:, ::-1]


def _principal_axes(centred: np.ndarray, k: int) -> np.ndarray:
    """(d, k') orthonormal principal axes of ``centred`` (n, d) rows, largest variance first,
    k' = min(k, d, n). With fewer rows than dimensions the n x n Gram matrix is decomposed
    instead of the d x d scatter matrix (d = 3528: seconds, and minutes on a loaded machine,
    where a threaded eigensolver stalls), and each axis is ``centred.T @ u`` normalised;
    axes the rows do not span (zero variance) are left out. Only the top k' eigenpairs are
    computed (_top_eigh)."""
    n, d = centred.shape
    k = min(k, n, d)
    if n >= d:
        return _top_eigh(centred.T @ centred, k)[1].copy()
    values, u = _top_eigh(centred @ centred.T, k)
    keep = values > values[0] * 1e-10 if values[0] > 0 else np.zeros(k, bool)
    axes = centred.T @ u[:, keep]
    return axes / np.linalg.norm(axes, axis=0)


class TemplatePose(PoseEstimator):
    """fit(frames, poses (n, 6)) -> self; predict(frames) -> (n, 6), NaN for an empty mask.
    Learned (FITTED, in model-file order; the file names them without the ``_``): the HOG
    mean and PCA basis, the templates' codes, poses, box geometry and distances, and the
    training focal length per image height."""

    FITTED = ("mean_", "basis_", "codes_", "poses_", "geometry_", "distance_", "focal_per_height_")
    DETERMINISTIC = True   # no seed; each frame is matched on its own

    def __init__(self, *, components: int = 128, size_neighbours: int = 15, ray_correction: bool = False):
        self.components = components
        self.size_neighbours = size_neighbours
        self.ray_correction = ray_correction

    def fit(self, frames, poses) -> "TemplatePose":

        desc = frame_descriptors(frames)
        poses = np.asarray(poses, dtype=np.float64)
        ok = np.isfinite(desc).all(axis=1)
        check_xy(desc[ok, :HOG_SIZE], poses[ok] if len(poses) == len(desc) else poses)
        self.mean_, self.basis_ = hog_projection(desc[ok, :HOG_SIZE], self.components)
        self.codes_ = project_hog(desc[ok, :HOG_SIZE], self.mean_, self.basis_)
        self.poses_ = poses[ok]
        self.geometry_ = desc[ok, HOG_SIZE:].astype(np.float64)
        self.distance_ = np.linalg.norm(self.poses_[:, 3:], axis=1)
        # For images without K (spm predict): the training focal length per image height (cy = (H - 1) / 2).
        self.focal_per_height_ = np.array(np.median(self.geometry_[:, 4] / (2 * self.geometry_[:, 6] + 1)))
        return self

    def _distance(self, geometry: np.ndarray) -> np.ndarray:
        """(m, 7) query geometry -> (m,) metres (distance_by_size over the templates)."""
        return distance_by_size(self.geometry_, self.distance_, geometry, self.size_neighbours)

    def nearest(self, hog: np.ndarray) -> np.ndarray:
        """(m, HOG_SIZE) descriptors -> (m,) index of the nearest template."""
        check_fitted(self, self.FITTED)
        z = project_hog(hog, self.mean_, self.basis_)
        sq = (self.codes_ ** 2).sum(axis=1)
        return np.concatenate([np.argmin(sq[None] - 2 * z[s: s + 1024] @ self.codes_.T, axis=1)
                               for s in range(0, len(z), 1024)]) if len(z) else np.zeros(0, np.int64)

    def predict_descriptors(self, desc: np.ndarray, K: np.ndarray) -> np.ndarray:
        """(n, HOG_SIZE + 7) descriptors, (n, 3, 3) K -> (n, 6) labels."""
        check_fitted(self, self.FITTED)
        out = np.full((len(desc), 6), np.nan)
        ok = np.isfinite(desc).all(axis=1)
        if not ok.any():
            return out
        j = self.nearest(desc[ok, :HOG_SIZE])
        g_q = desc[ok, HOG_SIZE:].astype(np.float64)
        out[ok] = place(self.poses_[j], self.geometry_[j], g_q, np.asarray(K, np.float64)[ok], self._distance(g_q),
                        self.ray_correction)
        return out

    def predict_image(self, rgb: np.ndarray, mask=None, K=None) -> dict:
        """One (H, W, 3) uint8 image, its (H, W) mask or region of interest (None: the
        whole image), K (None: the training images' field of view, centred) -> {"pose": (6,)}."""
        check_fitted(self, self.FITTED)
        h, w = rgb.shape[:2]
        if K is None:
            f = self.focal_per_height_ * h
            K = np.array([[f, 0, (w - 1) / 2], [0, f, (h - 1) / 2], [0, 0, 1.0]])
        mask = np.ones((h, w), bool) if mask is None else np.asarray(mask) > 0
        return {"pose": self.predict_descriptors(template_descriptor(rgb, mask, K)[None], K[None])[0]}

    def save(self, path):

        check_fitted(self, self.FITTED)
        params = {k: v for k, v in vars(self).items() if not k.endswith("_")}
        return save_model_file(path, "template", params, {k[:-1]: getattr(self, k) for k in self.FITTED})

    @classmethod
    def load(cls, path) -> "TemplatePose":

        return cls.from_model_file(*load_model_file(path, "template"))

    @classmethod
    def from_model_file(cls, header: dict, arrays: dict) -> "TemplatePose":
        """The model a file's (header, arrays) describe (load_model_file); KeyError naming the
        first missing array (in FITTED order); arrays it does not know are ignored."""
        return cls.from_state(**header["params"], **{k: arrays[k[:-1]] for k in cls.FITTED})


    def check_loaded(self) -> None:
        """ValueError when a loaded model's arrays do not fit together (a damaged or hand-made file)."""

        check_fitted(self, self.FITTED)
        n, k = len(self.poses_), self.basis_.shape[-1]
        need(self.mean_.shape == (HOG_SIZE,) and self.basis_.shape == (HOG_SIZE, k) and n > 0,
              f"mean {self.mean_.shape} and basis {self.basis_.shape}, expected ({HOG_SIZE},), ({HOG_SIZE}, k)")
        need(self.codes_.shape == (n, k) and self.poses_.shape == (n, 6)
              and self.geometry_.shape == (n, len(GEOMETRY)) and self.distance_.shape == (n,),
              f"templates of different lengths (codes {self.codes_.shape}, poses {self.poses_.shape}, "
              f"geometry {self.geometry_.shape}, distance {self.distance_.shape})")
        need(np.shape(self.focal_per_height_) == () and float(self.focal_per_height_) > 0,
              f"focal_per_height is {self.focal_per_height_!r}")
        need_finite(self.mean_, self.basis_, self.codes_, self.poses_, self.geometry_, self.distance_)

    def predict(self, frames) -> np.ndarray:
        check_fitted(self, self.FITTED)
        desc = frame_descriptors(frames)
        K = column(frames, "K", lambda f: np.asarray(f["K"], np.float64))
        return self.predict_descriptors(desc, K)


def hog_projection(hog: np.ndarray, components: int) -> tuple[np.ndarray, np.ndarray]:
    """(n, HOG_SIZE) descriptors -> the mean (HOG_SIZE,) of their unit rows and the top ``components``
    principal axes (HOG_SIZE, k) around it (_principal_axes): what project_hog maps with."""
    hog = _unit(hog)
    mean = hog.mean(axis=0)
    return mean, _principal_axes(hog - mean, components)


def project_hog(hog: np.ndarray, mean: np.ndarray, axes: np.ndarray, dtype=np.float64) -> np.ndarray:
    """(m, HOG_SIZE) descriptors -> (m, k) codes of ``dtype``: unit rows, centred on ``mean``, on ``axes``.
    Two codes' squared distance is that of the unit descriptors within the axes' span (2 - 2 cosine).
    The cnn keeps its codes in float32 (computed so, 4 to 8 times faster on one thread at 20,000 frames)."""
    return (_unit(hog, dtype) - np.asarray(mean, dtype)) @ np.asarray(axes, dtype)


def _unit(x: np.ndarray, dtype=np.float64) -> np.ndarray:
    x = np.asarray(x, dtype=dtype)
    return x / np.maximum(np.linalg.norm(x, axis=1, keepdims=True), 1e-12)


def distance_by_size(geometry_t: np.ndarray, distance_t: np.ndarray, geometry_q: np.ndarray, k: int) -> np.ndarray:
    """(m, 7) query geometry -> (m,) metres: the median distance ``distance_t`` of the ``k`` training
    frames (geometry ``geometry_t``) whose apparent size is closest: size in the image is inverse
    to distance, and objects are normalised to one size, so this transfers between classes."""
    size_t = np.log(geometry_t[:, 2] / geometry_t[:, 3])
    order = np.argsort(size_t)
    n = len(order)
    k = min(k, n)
    size_q = np.log(geometry_q[:, 2] / geometry_q[:, 3])
    pos = np.searchsorted(size_t[order], size_q)
    # The k nearest on a line lie in the 2k-window around the insertion point; at either end
    # of the sizes the window slides inwards (never clipped, which would repeat one frame).
    start = np.clip(pos - k, 0, max(n - 2 * k, 0))
    window = start[:, None] + np.arange(min(2 * k, n))[None]
    gap = np.abs(size_t[order][window] - size_q[:, None])
    nearest = np.take_along_axis(window, np.argsort(gap, axis=1, kind="stable")[:, :k], axis=1)
    return np.median(distance_t[order][nearest], axis=1)


def place(poses_t: np.ndarray, geometry_t: np.ndarray, geometry_q: np.ndarray, K_q: np.ndarray,
          distance_q: np.ndarray, ray_correction: bool = False) -> np.ndarray:
    """(m, 6) labels: each matched training frame's pose (``poses_t``, its box ``geometry_t``) moved
    to the query's box (``geometry_q``, ``K_q``) at ``distance_q`` metres (module docstring)."""
    R_t, t_t = label_to_pose(poses_t)
    # The template's object centre in its image, as an offset from its box centre in box sides.
    centre_t = t_t[:, :2] / t_t[:, 2:3] * geometry_t[:, 3:5] + geometry_t[:, 5:7]
    offset = (centre_t - geometry_t[:, :2]) / geometry_t[:, 2:3]
    ray_q = _rays(K_q, geometry_q[:, :2] + offset * geometry_q[:, 2:3])
    R_q = R_t
    if ray_correction:
        R_q = _rotation_between(t_t / np.linalg.norm(t_t, axis=1, keepdims=True), ray_q) @ R_t
    return pose_to_label(R_q, ray_q * distance_q[:, None])

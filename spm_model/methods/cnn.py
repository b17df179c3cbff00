"""The learned method (``cnn``): a small CNN trained on the training frames' object crops so
that nearby poses embed nearby, then nearest-neighbour retrieval in that embedding.

Input: the reference's crop (spm_model/methods/descriptors.py): the square around the visible
mask's box with a 5% margin, the grey image zeroed outside the mask, with the mask itself as a
second channel, ``side`` x ``side`` pixels. The background never reaches the network (the
mask is applied first, at training and test alike), so no background augmentation is needed.

Training (``fit``): the training rotations are covered by at most ``bins`` view bins (farthest
point sampling in the geodesic angle, deterministic; on a grid with fewer poses, one bin per
pose); each frame's target is a soft assignment to the bins, exp(-(angle / w)^2 / 2) normalised,
w half the median spacing of the bins, so neighbouring views are near neighbours in the loss
too. The network (spm_model/methods/cnn_net.py) is trained for a fixed budget of ``steps``
Adam steps of ``batch`` frames (seconds on one CPU thread, whatever the number of frames; the
cost is recorded in ``training_``), each crop augmented on the fly: with probability one half,
black rectangles over 0 to ``occlusion`` of the object drawn exactly as ``spm-data occlude``
draws them (spm_data/core/occlusion.py), the crop then re-cut to the box of what is still
visible (as a test frame's visible mask gives it), and a brightness and contrast jitter.
Plain rotation regression from few views fails (issue 48's probe: 0% within 5 degrees); bins
plus retrieval do not need to interpolate between poses.

Prediction: the training frame with the best score cos(embeddings) + ``hog_weight`` x cos(HOG),
every training frame scored (``rerank`` -1, the default; spm_model/methods/cnn_retrieval.py), and
its rotation; translation from the crop geometry and K exactly as the reference does (template.py
``place``, ``distance_by_size``). The HOG is that of the stored 64 x 64 masked grey crop (exactly
the reference's template crop and descriptor, so a benchmark split reads the training frames' HOG from
the feature cache: cnn_retrieval.cached_hogs), compared in its top ``hog_components`` principal
axes (template.py ``hog_projection``, fitted on at most AXES_ROWS training frames spread evenly;
the codes of every training frame are kept, float32). The weight 16 was chosen on held-out
training frames (benchmarks/cnn_rerank.py; docs/method.md): HOG carries most of the score, and
the network's term moves the choice where HOG's neighbours are close. ``rerank`` k >= 2 scores
only the k nearest embeddings (the re-ranking this replaced); 0 or 1: the nearest embedding
alone (no HOG is computed).

Symmetries: not modelled in the loss (frames know none). Views a symmetry makes identical get
different bins the network cannot tell apart; retrieval then returns one of the equivalent
training poses, which the benchmark's symmetry-aware errors score as correct.

Seeded (``seed``), deterministic on the CPU (torch's deterministic algorithms, ``threads``
intra-op threads, 1 by default as benchmark jobs run); ``device`` "auto" uses a GPU when torch
sees one (the same code; results then differ from the CPU's in rounding).
"""

from __future__ import annotations

import numpy as np

from spm_data.core.occlusion import black_out, occlude_mask
from spm_data.core.poses import label_to_pose
from spm_model.errors import ModelError
from spm_model.base.estimator import PoseEstimator, check_fitted
from spm_model.base.model_files import load_model_file, need, need_finite, save_model_file
from spm_model.methods import cnn_net
from spm_model.methods.cnn_retrieval import (SHORTLISTS, cached_hogs, crop_hogs, nearest_frames, uses_hog,
                                             valid_shortlist)
from spm_model.methods.descriptors import GEOMETRY, HOG_SIZE, SIDE, box_of, crop_box, masked_grey
from spm_model.methods.template import distance_by_size, hog_projection, place, project_hog

CROP = SIDE   # the stored crop's side (the reference's 64): augmentation re-cuts the network's input from it
AXES_ROWS = 2048   # at most this many training frames fit the HOG axes (seconds, not a minute, at 20k frames)


def frame_crop(rgb: np.ndarray, mask: np.ndarray, K: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(2, CROP, CROP) uint8 (masked grey, mask as 0/255) and (7,) GEOMETRY of one frame; zeros and
    NaN geometry when its mask is empty."""
    mask = np.asarray(mask) > 0
    box = box_of(mask)
    if box is None:
        return np.zeros((2, CROP, CROP), np.uint8), np.full(len(GEOMETRY), np.nan)
    grey = crop_box(masked_grey(rgb, mask), box, CROP)
    visible = crop_box(mask.astype(np.uint8) * 255, box, CROP)
    K = np.asarray(K, np.float64)
    return np.stack([grey, visible]), np.array([*box, K[0, 0], K[1, 1], K[0, 2], K[1, 2]])


def frame_crops(frames) -> tuple[np.ndarray, np.ndarray]:
    """(n, 2, CROP, CROP) uint8 crops and (n, 7) geometry of a frame sequence."""
    crops, geometry = np.zeros((len(frames), 2, CROP, CROP), np.uint8), np.full((len(frames), len(GEOMETRY)), np.nan)
    for i, f in enumerate(frames):
        crops[i], geometry[i] = frame_crop(f["rgb"], f["mask"], f["K"])
    return crops, geometry


def net_input(crop: np.ndarray, side: int) -> np.ndarray:
    """(2, CROP, CROP) uint8 -> (2, side, side) float32 in [0, 1]: re-cut to its visible box."""
    box = box_of(crop[1] > 127)
    if box is None:
        return np.zeros((2, side, side), np.float32)
    return np.stack([crop_box(np.ascontiguousarray(c), box, side) for c in crop]).astype(np.float32) / 255.0


def augmented(crop: np.ndarray, side: int, occlusion: float, rng: np.random.Generator) -> np.ndarray:
    """One training input: ``crop`` occluded (half the time), re-cut, brightness/contrast jittered."""
    grey, visible = crop[0].copy(), crop[1].copy()
    if occlusion > 0 and rng.random() < 0.5:
        cover = occlude_mask(visible > 127, rng.uniform(0.0, occlusion), rng)
        if cover.fraction < 0.95:
            black_out(grey, visible, rects=cover.rects)
    seen = visible > 127
    grey = np.where(seen, np.clip(grey * rng.uniform(0.7, 1.3) + rng.uniform(-25, 25), 0, 255), 0).astype(np.uint8)
    return net_input(np.stack([grey, visible]), side)


def rotation_quaternions(poses: np.ndarray) -> np.ndarray:
    """(n, 6) labels -> (n, 4) unit quaternions of their rotations (sign arbitrary)."""
    from scipy.spatial.transform import Rotation

    return Rotation.from_matrix(label_to_pose(np.asarray(poses, np.float64))[0]).as_quat()


def angles_to(q: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """(n, 4), (m, 4) -> (n, m) geodesic angles (radians) between the rotations."""
    return 2 * np.arccos(np.clip(np.abs(q @ centre.T), 0.0, 1.0))


def view_bins(q: np.ndarray, count: int) -> np.ndarray:
    """Indices of at most ``count`` rotations of ``q`` spread by farthest point sampling (the first
    frame first; ties to the lowest index): deterministic, and every distinct rotation when fewer."""
    chosen, gap = [0], angles_to(q, q[:1])[:, 0]
    while len(chosen) < min(count, len(q)) and gap.max() > 1e-6:
        chosen.append(int(np.argmax(gap)))
        gap = np.minimum(gap, angles_to(q, q[chosen[-1]: chosen[-1] + 1])[:, 0])
    return np.array(chosen)


def soft_targets(q: np.ndarray, centres: np.ndarray, spread: float = 0.5) -> np.ndarray:
    """(n, bins) float32 rows summing to 1: exp(-(angle / w)^2 / 2) to each bin, w ``spread`` times
    the bins' median spacing (at least 1 degree)."""
    if len(centres) == 1:
        return np.ones((len(q), 1), np.float32)
    between = angles_to(centres, centres) + np.eye(len(centres)) * 10
    width = max(np.median(between.min(axis=1)) * spread, np.radians(1.0))
    w = np.exp(-0.5 * (angles_to(q, centres) / width) ** 2)
    w[w < 1e-4] = 0
    w[np.arange(len(q)), np.argmax(w, axis=1)] += 1e-6   # never an all-zero row
    return (w / w.sum(axis=1, keepdims=True)).astype(np.float32)


def check_device(device: str) -> str:
    """``device`` as the cnn method resolves it ("auto" -> "cuda" or "cpu"); ModelError, one line, when
    torch is not installed or cannot use it (cnn_net.resolve_device): spm train, evaluate and predict
    check --device with it before any work."""
    return cnn_net.resolve_device(cnn_net.torch_module(), device)


def device_note(device: str) -> str | None:
    """The one line saying where the cnn method will run ("cnn device: cpu (auto: torch sees no GPU
    here, so the CPU)", cnn_net.device_line), for spm train to print before any work; None when
    torch is not installed and ``device`` is "auto" (the method is then declined with the install
    hint, the other methods run). ModelError, one line, for a device torch cannot use."""
    if device == "auto":
        try:
            import torch   # noqa: F401  (only whether it is there)
        except ImportError:
            return None
    return cnn_net.device_line(cnn_net.torch_module(), device)


class CNNPose(PoseEstimator):
    """fit(frames, poses (n, 6)) -> self; predict(frames) -> (n, 6), NaN for an empty mask.
    Learned (FITTED): the network's arrays by torch's names (``net_``), the bin rotations, the
    training frames' embeddings, poses, box geometry and distances, the training focal length per
    image height, and the HOG codes' mean, axes and training codes (empty when ``rerank`` is 0 or 1);
    ``training_`` says what training cost. A query takes the pose of the training frame scoring best by
    cos(embeddings) + ``hog_weight`` x cos(HOG in ``hog_components`` axes), among every training frame
    (``rerank`` -1) or the ``rerank`` nearest embeddings; 0 or 1: the nearest embedding (module docstring)."""

    FITTED = ("net_", "bins_", "embeddings_", "poses_", "geometry_", "distance_", "focal_per_height_",
              "hog_mean_", "hog_axes_", "hog_codes_")

    @staticmethod
    def check_available() -> None:
        """ModelError, one line naming the extra ``learn``, when torch is not installed."""
        cnn_net.torch_module()

    def __init__(self, *, side: int = 32, width: int = 16, embed: int = 64, bins: int = 256, steps: int = 500,
                 epochs: float = 40.0, batch: int = 64, lr: float = 0.005, occlusion: float = 0.6, seed: int = 0,
                 threads: int = 1, device: str = "auto", size_neighbours: int = 15, spread: float = 0.5,
                 rerank: int = -1, hog_weight: float = 16.0, hog_components: int = 128):
        self.side, self.width, self.embed, self.bins = side, width, embed, bins
        self.steps, self.epochs, self.batch, self.lr, self.occlusion = steps, epochs, batch, lr, occlusion
        self.seed, self.threads, self.device, self.size_neighbours = seed, threads, device, size_neighbours
        self.spread, self.rerank, self.hog_weight, self.hog_components = spread, rerank, hog_weight, hog_components

    def fit(self, frames, poses) -> "CNNPose":
        torch = cnn_net.torch_module()
        if self.side % 16 or self.side < 16:
            raise ModelError(f"CNNPose side must be a multiple of 16 (four 2x2 poolings), got {self.side}")
        if not valid_shortlist(self.rerank):
            raise ModelError(f"CNNPose rerank must be {SHORTLISTS}, got {self.rerank!r}")
        crops, geometry = frame_crops(frames)
        poses = np.asarray(poses, np.float64)
        ok = np.isfinite(geometry).all(axis=1) & np.isfinite(poses).all(axis=1)
        if not ok.any():
            raise ModelError("CNNPose.fit: no training frame has an object in its mask and a finite pose")
        crops, geometry, poses = crops[ok], geometry[ok], poses[ok]
        q = rotation_quaternions(poses)
        centres = q[view_bins(q, self.bins)]
        targets = soft_targets(q, centres, self.spread)
        rng = np.random.default_rng(self.seed)
        device = cnn_net.resolve_device(torch, self.device)

        def batches(step):
            index = rng.integers(0, len(crops), size=self.batch)
            return index, np.stack([augmented(crops[i], self.side, self.occlusion, rng) for i in index])

        with cnn_net.torch_settings(torch, self.seed, self.threads):
            net = cnn_net.make_net(torch, self.side, self.width, self.embed, len(centres))
            cost = cnn_net.train_net(torch, net, batches, targets, steps=self.budget(len(crops)), lr=self.lr,
                                     device=device)
            plain = np.stack([net_input(c, self.side) for c in crops])
            self.embeddings_ = cnn_net.embed_all(torch, net, plain, device)
        self.net_ = cnn_net.state_arrays(net)
        self._module = net
        self.bins_, self.poses_, self.geometry_ = centres, poses, geometry
        self.distance_ = np.linalg.norm(poses[:, 3:], axis=1)
        self.focal_per_height_ = np.array(np.median(geometry[:, 4] / (2 * geometry[:, 6] + 1)))
        self._fit_hog(frames, ok, crops)
        self.training_ = {**cost, "frames": int(len(crops)),
                          "epochs": round(cost["steps"] * self.batch / len(crops), 3)}
        return self

    def _fit_hog(self, frames, ok: np.ndarray, crops: np.ndarray) -> None:
        """The HOG codes' state from the training frames kept, ``ok`` ((len(frames),) bool), whose
        (k, 2, CROP, CROP) uint8 crops are ``crops``: their HOG read from the frames where they carry it
        (cnn_retrieval.cached_hogs), else (or when any kept row is not finite) all computed. Empty
        arrays when retrieval uses no HOG."""
        if not uses_hog(self.rerank):
            self.hog_mean_, self.hog_axes_ = np.zeros(0, np.float32), np.zeros((0, 0), np.float32)
            self.hog_codes_ = np.zeros((len(crops), 0), np.float32)
            return
        cached = cached_hogs(frames)
        kept = None if cached is None else cached[ok]
        hogs = kept if kept is not None and np.isfinite(kept).all() else crop_hogs(crops)
        mean, axes = hog_projection(hogs[:: -(-len(hogs) // AXES_ROWS)], self.hog_components)
        self.hog_mean_, self.hog_axes_ = mean.astype(np.float32), axes.astype(np.float32)
        self.hog_codes_ = project_hog(hogs, self.hog_mean_, self.hog_axes_, np.float32)

    def nearest(self, z: np.ndarray, crops: np.ndarray) -> np.ndarray:
        """(m, embed) unit embeddings of the queries, their (m, 2, CROP, CROP) crops -> (m,) index of the
        training frame each retrieves (spm_model/methods/cnn_retrieval.py; ``rerank`` is its shortlist)."""
        codes = None
        if uses_hog(self.rerank):
            codes = project_hog(crop_hogs(crops), self.hog_mean_, self.hog_axes_, np.float32)
        return nearest_frames(z, self.embeddings_, codes, self.hog_codes_, self.hog_weight, self.rerank)

    def budget(self, frames: int) -> int:
        """Gradient steps for ``frames`` training frames: ``steps``, or fewer where ``epochs`` passes
        over the frames take fewer (at least one step)."""
        return max(1, min(int(self.steps), int(np.ceil(self.epochs * frames / self.batch))))

    def __getstate__(self):
        """Pickled (a final model sent back from a benchmark worker) without the torch module, which
        ``_net`` rebuilds from ``net_`` when first needed (a GPU's tensors never travel)."""
        return {k: v for k, v in self.__dict__.items() if k != "_module"}

    def _net(self, torch):
        if getattr(self, "_module", None) is None:
            self._module = cnn_net.net_from_arrays(torch, self.net_, self.side, self.width, self.embed,
                                                   len(self.bins_))
        return self._module

    def predict_crops(self, crops: np.ndarray, geometry: np.ndarray, K: np.ndarray) -> np.ndarray:
        """(n, 2, CROP, CROP) crops, (n, 7) geometry, (n, 3, 3) K -> (n, 6) labels (NaN rows without a box)."""
        check_fitted(self, self.FITTED)
        torch = cnn_net.torch_module()
        out = np.full((len(crops), 6), np.nan)
        ok = np.isfinite(geometry).all(axis=1)
        if not ok.any():
            return out
        device = cnn_net.resolve_device(torch, self.device)
        with cnn_net.torch_settings(torch, self.seed, self.threads):
            z = cnn_net.embed_all(torch, self._net(torch), np.stack([net_input(c, self.side) for c in crops[ok]]),
                                  device)
        j = self.nearest(z, crops[ok])
        g_q = geometry[ok]
        out[ok] = place(self.poses_[j], self.geometry_[j], g_q, np.asarray(K, np.float64)[ok],
                        distance_by_size(self.geometry_, self.distance_, g_q, self.size_neighbours))
        return out

    def predict(self, frames) -> np.ndarray:
        check_fitted(self, self.FITTED)
        crops, geometry = frame_crops(frames)
        return self.predict_crops(crops, geometry, np.stack([np.asarray(f["K"], np.float64) for f in frames])
                                  if len(frames) else np.zeros((0, 3, 3)))

    def predict_image(self, rgb: np.ndarray, mask=None, K=None) -> dict:
        """One (H, W, 3) uint8 image, its mask or region of interest (None: the whole image), K (None:
        the training images' field of view, centred) -> {"pose": (6,)}."""
        check_fitted(self, self.FITTED)
        h, w = rgb.shape[:2]
        if K is None:
            f = float(self.focal_per_height_) * h
            K = np.array([[f, 0, (w - 1) / 2], [0, f, (h - 1) / 2], [0, 0, 1.0]])
        mask = np.ones((h, w), bool) if mask is None else np.asarray(mask) > 0
        crop, geometry = frame_crop(rgb, mask, K)
        return {"pose": self.predict_crops(crop[None], geometry[None], K[None])[0]}

    def save(self, path):
        """The sealed model file (kind "cnn") and, beside it, the same arrays as PATH.safetensors."""
        from spm_model.base.safetensors_file import write_safetensors

        check_fitted(self, self.FITTED)
        arrays = {**{f"net/{k}": v for k, v in self.net_.items()},
                  **{k[:-1]: getattr(self, k) for k in self.FITTED if k != "net_"}}
        extra = {"training": getattr(self, "training_", None)}
        saved = save_model_file(path, "cnn", self.get_params(), arrays, extra)
        write_safetensors(saved.with_suffix(".safetensors"), {k.replace("/", "."): v for k, v in arrays.items()},
                          {"kind": "spm cnn", "params": self.get_params(), **extra})
        return saved

    @classmethod
    def load(cls, path) -> "CNNPose":
        return cls.from_model_file(*load_model_file(path, "cnn"))

    @classmethod
    def from_model_file(cls, header: dict, arrays: dict) -> "CNNPose":
        """The model a file's (header, arrays) describe; KeyError naming the first missing array. A file
        saved before the HOG re-ranking (no ``rerank`` in its parameters) loads as ``rerank`` 0: the nearest
        embedding, as it predicted then."""
        net = {k[4:]: v for k, v in arrays.items() if k.startswith("net/")}
        if not net:
            raise KeyError("net/...")
        params = header["params"] if "rerank" in header["params"] else {**header["params"], "rerank": 0}
        hog = {} if uses_hog(params["rerank"]) else {"hog_mean": np.zeros(0), "hog_axes": np.zeros((0, 0)),  # saved
                                                     "hog_codes": np.zeros((len(arrays["poses"]), 0))}  # before HOG
        model = cls.from_state(**params, net_=net, **{k: {**arrays, **hog}[k[:-1]] for k in cls.FITTED if k != "net_"})
        model.training_ = header.get("training")
        return model

    def check_loaded(self) -> None:
        """ValueError when a loaded model's arrays do not fit together (a damaged or hand-made file)."""
        check_fitted(self, self.FITTED)
        need(valid_shortlist(self.rerank), f"rerank is {self.rerank!r}: {SHORTLISTS}")
        n = len(self.poses_)
        need(n > 0 and self.embeddings_.shape == (n, self.embed) and self.poses_.shape == (n, 6)
             and self.geometry_.shape == (n, len(GEOMETRY)) and self.distance_.shape == (n,),
             f"training frames of different lengths (embeddings {self.embeddings_.shape}, poses "
             f"{self.poses_.shape}, geometry {self.geometry_.shape}, distance {self.distance_.shape})")
        need(self.bins_.ndim == 2 and self.bins_.shape[1] == 4, f"bins of shape {self.bins_.shape}, expected (b, 4)")
        need(np.shape(self.focal_per_height_) == () and float(self.focal_per_height_) > 0,
             f"focal_per_height is {self.focal_per_height_!r}")
        c = self.hog_axes_.shape[-1] if self.hog_axes_.ndim == 2 else -1
        need(not uses_hog(self.rerank) or (c > 0 and self.hog_mean_.shape == (HOG_SIZE,)
                                 and self.hog_axes_.shape == (HOG_SIZE, c) and self.hog_codes_.shape == (n, c)),
             f"HOG code arrays of shapes mean {self.hog_mean_.shape}, axes {self.hog_axes_.shape}, codes "
             f"{self.hog_codes_.shape}; expected ({HOG_SIZE},), ({HOG_SIZE}, c), ({n}, c) with rerank {self.rerank}")
        need_finite(self.embeddings_, self.poses_, self.geometry_, self.distance_, self.hog_mean_, self.hog_axes_,
                    self.hog_codes_, *self.net_.values())
        self._net(cnn_net.torch_module())

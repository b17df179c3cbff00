"""SMM: pose classification by statistical manifold modelling (Mei, Liu, Hero & Savarese,
"Robust Object Pose Estimation via Statistical Manifold Modeling", CVPR 2011).

Stages (decisions where the paper is silent: docs/method.md, "SMM"):

1. Parts (spm_model/methods/smm_parts.py): local SIFT features in the mask; candidate
   parts are components of their joint appearance-geometry distribution.
2. Part selection (spm_model/methods/smm_graph.py): the parts whose constellation
   aligns the training sequences' pose manifolds (frames at one pose close across
   sequences) and expands them (frames of one sequence at different poses far
   apart), chosen as a maximum-weight subgraph.
3. Pose classification: the pose class (an azimuth bin, :func:`pose_bins`) voted by
   the nearest training frames under the selected parts' manifold distance.
   ``predict`` returns the rotation of the nearest training frame of the voted class
   and a translation scaled from it by the object's apparent size.

Training frames need "rgb", "mask", "K" and "sequence"; test frames "rgb", "mask", "K".
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from spm_data.core.poses import label_to_pose, label_to_view, wrap_degrees
from spm_model.errors import ModelError
from spm_model.base.estimator import Needs, PoseEstimator
from spm_model.base.ranking import smallest_k
from spm_model.methods.smm_graph import manifold_distances, select_parts, selection_weights, training_pairs
from spm_model.methods.smm_parts import fit_codebook, mask_frame, remembered_local_features

PAPER_BINS = 8  # azimuth classes of 45 degrees, centred on 0, 45, ..., 315


def bin_centres(n_bins: int = PAPER_BINS) -> np.ndarray:
    """(n_bins,) azimuths of the pose classes' centres, degrees in (-180, 180]."""
    return wrap_degrees(np.arange(n_bins) * 360.0 / n_bins)


def pose_bins(labels, n_bins: int = PAPER_BINS) -> np.ndarray:
    """The pose class of each label (n, 6): the azimuth bin of its viewpoint
    (spm_data.core.poses.label_to_view), bins of 360/n_bins degrees centred on
    0, 360/n_bins, ...; (n,) int64 in [0, n_bins), -1 for a NaN label."""
    labels = np.asarray(labels, dtype=np.float64).reshape(-1, 6)
    out = np.full(len(labels), -1, dtype=np.int64)
    ok = np.isfinite(labels).all(axis=1)
    if ok.any():
        azimuth = np.atleast_1d(label_to_view(labels[ok])["azimuth"])
        width = 360.0 / n_bins
        out[ok] = np.floor(np.mod(azimuth + width / 2.0, 360.0) / width).astype(np.int64) % n_bins
    return out


def _check_frame(frame, keys, i: int, call: str) -> None:
    if not hasattr(frame, "keys") or any(k not in frame for k in keys):
        got = sorted(frame.keys()) if hasattr(frame, "keys") else type(frame).__name__
        raise ModelError(f"SMMPose.{call}: frame {i} needs keys {list(keys)}, got {got}; "
                         "pass frames as spm_model.base.frames gives them (dicts)")


class SMMPose(PoseEstimator):
    """Statistical manifold modelling, built from its paper (module docstring).

    n_bins: pose classes (azimuth bins; 8, our reading of the paper's). candidate_parts: parts learned
    from the joint appearance-geometry distribution; parts: how many the graph
    selection keeps. alignment_weight: weight of the intra-class (alignment) term
    against the inter-pose (expansion) term. neighbours: training frames voting for a
    pose class. max_features: SIFT keypoints per image. codebook_frames: training
    frames whose features learn the parts. align_tolerance: degrees within which two
    frames of different sequences count as one pose. max_pairs: frame pairs per term.
    geometry_weight: weight of position against appearance in the joint space."""

    FITTED = ("codebook_", "selected_", "presence_", "location_", "poses_", "bins_",
              "centroids_", "scales_", "intrinsics_", "objective_")
    # Part selection aligns the pose manifolds of different camera paths: two at least.
    NEEDS = Needs(frames=2, sequences=2)

    def __init__(self, *, n_bins: int = PAPER_BINS, candidate_parts: int = 96, parts: int = 48,
                 alignment_weight: float = 1.0, neighbours: int = 5, max_features: int = 80,
                 codebook_frames: int = 600, align_tolerance: float = 5.0, max_pairs: int = 4000,
                 geometry_weight: float = 4.0, seed: int = 0):
        self.n_bins = n_bins
        self.candidate_parts = candidate_parts
        self.parts = parts
        self.alignment_weight = alignment_weight
        self.neighbours = neighbours
        self.max_features = max_features
        self.codebook_frames = codebook_frames
        self.align_tolerance = align_tolerance
        self.max_pairs = max_pairs
        self.geometry_weight = geometry_weight
        self.seed = seed

    def _features(self, frames, call: str, keys=("rgb", "mask", "K")):
        """Per frame: local features, mask centroid and scale, K; and the ``keys[3:]`` values."""
        feats, centroids, scales, Ks, extra = [], [], [], [], []
        for i, frame in enumerate(frames):
            _check_frame(frame, keys, i, call)
            mask = np.asarray(frame["mask"]) > 0
            feats.append(remembered_local_features(frame["rgb"], mask, self.max_features))
            box = mask_frame(mask)
            centroids.append(box[0] if box else np.full(2, np.nan))
            scales.append(box[1] if box else np.nan)
            Ks.append(np.asarray(frame["K"], dtype=np.float64).reshape(3, 3))
            extra.append([frame[k] for k in keys[3:]])
        return feats, np.array(centroids).reshape(-1, 2), np.array(scales), np.array(Ks).reshape(-1, 3, 3), extra

    def _detect(self, feats, codebook, selected=None):
        found = [codebook.detect(g, a) for g, a in feats]
        presence = np.array([p for p, _ in found]).reshape(len(feats), codebook.size)
        location = np.array([m for _, m in found]).reshape(len(feats), codebook.size, 2)
        if selected is None:
            return presence, location
        return presence[:, selected].astype(np.float64), location[:, selected]

    def fit(self, frames, poses) -> "SMMPose":
        poses = np.asarray(poses, dtype=np.float64)
        if poses.ndim != 2 or poses.shape[1] != 6 or len(poses) != len(frames) or not np.isfinite(poses).all():
            raise ModelError(f"SMMPose.fit: expected finite poses of shape ({len(frames)}, 6), one row per frame, "
                             f"got {poses.shape}; pass the frames' labels (rx, ry, rz degrees, t metres)")
        if not 2 <= self.n_bins <= 360 or not 1 <= self.parts <= self.candidate_parts or self.neighbours < 1:
            raise ModelError(f"SMMPose: expected 2 <= n_bins <= 360, 1 <= parts <= candidate_parts and neighbours >= "
                             f"1, "
                             f"got n_bins={self.n_bins}, parts={self.parts}, candidate_parts={self.candidate_parts}, "
                             f"neighbours={self.neighbours}; fix the parameters")
        feats, centroids, scales, Ks, extra = self._features(frames, "fit", ("rgb", "mask", "K", "sequence"))
        sequences = np.array([e[0] for e in extra])
        rng = np.random.default_rng(self.seed)
        pool = rng.choice(len(feats), size=min(len(feats), self.codebook_frames), replace=False)
        geometry = np.vstack([feats[i][0] for i in pool])
        appearance = np.vstack([feats[i][1] for i in pool])
        codebook = fit_codebook(geometry, appearance, self.candidate_parts, geometry_weight=self.geometry_weight,
                                seed=self.seed)
        presence, location = self._detect(feats, codebook)
        bins = pose_bins(poses, self.n_bins)
        quaternions = Rotation.from_matrix(label_to_pose(poses)[0]).as_quat()
        align, expand = training_pairs(quaternions, sequences, bins, self.align_tolerance, self.max_pairs, self.seed,
                                       presence, location)
        if len(align) == 0 or len(expand) == 0:
            raise ModelError(f"SMMPose.fit: found {len(align)} same-pose pairs across sequences and {len(expand)} "
                             "different-pose pairs within one; train on at least two sequences (camera paths) "
                             f"that share poses within {self.align_tolerance} degrees and span two pose classes")
        W = selection_weights(presence, location, align, expand, self.alignment_weight)
        self.selected_ = select_parts(W, self.parts)
        self.objective_ = W
        self.codebook_ = codebook
        self.presence_ = presence[:, self.selected_].astype(np.float64)
        self.location_ = location[:, self.selected_]
        self.poses_, self.bins_ = poses.copy(), bins
        self.centroids_, self.scales_, self.intrinsics_ = centroids, scales, Ks
        return self

    def features_found(self, frames) -> np.ndarray:
        """(n,) bool: the frames SIFT found local features on (remembered: no SIFT after predict)."""
        return np.array([len(remembered_local_features(f["rgb"], np.asarray(f["mask"]) > 0, self.max_features)[0]) > 0
                         for f in frames], dtype=bool)

    def _match(self, frames):
        """Per test frame: voted pose class (-1: no estimate), matched training row, and
        the frame's centroid, scale and K."""
        self.check_fitted()
        feats, centroids, scales, Ks, _ = self._features(frames, "predict")
        klass = np.full(len(feats), -1, dtype=np.int64)
        match = np.full(len(feats), -1, dtype=np.int64)
        if not feats:
            return klass, match, centroids, scales, Ks
        presence, location = self._detect(feats, self.codebook_, self.selected_)
        k = min(self.neighbours, len(self.poses_))
        for start in range(0, len(feats), 64):
            rows = np.arange(start, min(start + 64, len(feats)))
            d = manifold_distances(presence[rows], location[rows], self.presence_, self.location_)
            nearest = smallest_k(d, k)
            for r, near in zip(rows, nearest):
                if presence[r].any():
                    klass[r], match[r] = vote(self.bins_, near, self.n_bins)
        return klass, match, centroids, scales, Ks

    def predict_bins(self, frames) -> np.ndarray:
        """(n,) int64 pose class of each frame (:func:`pose_bins`), -1 without an estimate."""
        return self._match(frames)[0]

    def predict(self, frames) -> np.ndarray:
        """(n, 6) labels: the matched training frame's rotation and the translation it
        implies at this frame's apparent size and position; NaN rows without an estimate."""
        klass, match, centroids, scales, Ks = self._match(frames)
        out = np.full((len(klass), 6), np.nan)
        for i in np.flatnonzero(match >= 0):
            j = match[i]
            out[i, :3] = self.poses_[j, :3]
            out[i, 3:] = scaled_translation(self.poses_[j, 3:], self.intrinsics_[j], self.centroids_[j],
                                            self.scales_[j], Ks[i], centroids[i], scales[i])
        return out


def vote(bins, nearest, n_bins: int):
    """Pose class voted by training rows ``nearest`` (nearest first) with classes
    ``bins``: the most votes, a tie going to the class of the nearest voter among the
    tied; returns (class, the nearest row of that class)."""
    votes = np.bincount(bins[nearest], minlength=n_bins)
    winner = next(bins[j] for j in nearest if votes[bins[j]] == votes.max())
    return int(winner), int(next(j for j in nearest if bins[j] == winner))


def scaled_translation(t_train, K_train, centroid_train, scale_train, K, centroid, scale) -> np.ndarray:
    """Translation (3,) metres of a test view matched to a training view. The size ratio
    ``scale / scale_train`` (scale: sqrt of the mask's area, pixels) divides the training
    depth (times the focal ratio); the object origin is put at the test mask's centroid
    plus the training view's offset (origin's projection minus its centroid, pixels)
    times the size ratio, and back-projected at that depth through ``K``."""
    t_train = np.asarray(t_train, dtype=np.float64)
    K_train, K = np.asarray(K_train, dtype=np.float64), np.asarray(K, dtype=np.float64)
    ratio = scale / scale_train
    focal = (K[0, 0] + K[1, 1]) / (K_train[0, 0] + K_train[1, 1])
    z = t_train[2] * focal / ratio
    origin = K_train @ t_train
    uv = np.asarray(centroid) + (origin[:2] / origin[2] - np.asarray(centroid_train)) * ratio
    return z * np.linalg.solve(K, np.array([uv[0], uv[1], 1.0]))

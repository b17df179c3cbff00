"""N3M: Natural 3D Markers (Hinterstoisser, Benhimane, Navab, ICCV 2007) as a pose
estimator: 3-D feature points learnt from posed training views with depth, markers
chosen among them, and a continuous 6-DoF pose per test image by matching, multi-level
validation and PnP. The stages: n3m_points (points and scores), n3m_select (markers),
n3m_pose (online); decisions where the paper is silent: docs/method.md, "N3M".

:class:`SiftPoints` is what N3M shares with the SIFT + PnP baseline (sift_pnp.py, not
in any paper): the 3-D points, the matching and the global test; :class:`N3MPose` adds
the points' scores and the markers.

Training frames are read for "rgb", "mask", "depth", "K" and (optionally) "sequence";
test frames for "rgb", "mask", "K" only.
"""

from __future__ import annotations

from abc import abstractmethod

import numpy as np

from spm_data.core.poses import label_to_pose, pose_to_label
from spm_model.errors import ModelError
from spm_model.base.estimator import Needs, PoseEstimator
from spm_model.methods import n3m_points as pts
from spm_model.methods import sift_points_memo as memo
from spm_model.methods.n3m_pose import estimate, match
from spm_model.methods.n3m_select import select_markers

TRAIN_KEYS = ("rgb", "mask", "depth", "K")
TEST_KEYS = ("rgb", "mask", "K")


class SiftPoints(PoseEstimator):
    """What N3M and SIFT + PnP share: SIFT keypoints of posed training views lifted to 3-D
    points of their object (``fit``: :meth:`_lift_points`), and per test image its keypoints
    matched to them and a pose that must explain ``min_inliers`` of all the matches
    (:meth:`_pose`, each subclass's own). Their shared parameters (keyword-only; pixels are
    the input image's):

    sift_side: images whose shorter side is below it are upsampled to it before SIFT.
    max_keypoints: SIFT keypoints kept per image (strongest).
    max_train_frames: training frames used at most, evenly spaced over the input.
    merge_pixels: observations closer than this many pixels (at the median training
        depth and focal length) are one 3-D point.
    descriptors_per_point: stored descriptors per 3-D point, spread over its views.
    ratio: the nearest-descriptor ratio of matching (and of N3M's distinctiveness).
    reprojection_error: pixels, the inlier threshold of every geometric check.
    min_inliers: inliers the final pose needs (else a NaN row).

    No seed: the FLANN kd-trees are drawn with a fixed seed (n3m_points.TREE_SEED) and
    OpenCV's RANSAC with its own fixed one, so fit and predict repeat exactly on any
    worker, and the benchmark fits these methods once when every run has the same splits.
    SIFT of an image is remembered (n3m_points.remembered_sift_features) under the same key
    for every subclass: with equal sift_side and max_keypoints they extract it once.
    """

    DETERMINISTIC = True
    NEEDS = Needs(frames=2, depth=True)  # 3-D points are lifted from depth, seen in 2 views or more

    FITTED = ("points_", "point_object_", "descriptors_", "descriptor_point_", "merge_radius_")

    def __init__(self, *, sift_side=256, max_keypoints=300, max_train_frames=1500, merge_pixels=1.5,
                 descriptors_per_point=6, ratio=0.8, reprojection_error=3.0, min_inliers=6):
        self.sift_side = sift_side
        self.max_keypoints = max_keypoints
        self.max_train_frames = max_train_frames
        self.merge_pixels = merge_pixels
        self.descriptors_per_point = descriptors_per_point
        self.ratio = ratio
        self.reprojection_error = reprojection_error
        self.min_inliers = min_inliers

    # ------------------------------------------------------------------ fit
    def _lift_points(self, frames, poses) -> tuple[dict, list]:
        """Learn the 3-D points from posed ``frames`` (keys TRAIN_KEYS, and "sequence": one id
        per object/camera path, default 0) and checked ``poses`` (n, 6); sets every attribute
        of SiftPoints.FITTED. Returns the observations and the per-object points (for N3M's
        scores)."""
        obs = self._observe(frames, poses)
        if len(obs["xyz"]) == 0:
            raise ModelError(f"{type(self).__name__}: SIFT found no keypoint on the objects of the training "
                             "frames; check their masks and depth, or raise sift_side")
        # N3M and SIFT + PnP with the same parameters merge the same observations: once a process.
        key = memo.observations_key((self.merge_pixels, self.descriptors_per_point), obs)
        parts, stored = memo.remembered_points(key, lambda: self._merged_points(obs))
        for name, value in stored.items():
            setattr(self, name, value)
        return obs, parts

    def _merged_points(self, obs) -> tuple[list, dict]:
        """The per-object points of ``obs`` and the database (SiftPoints.FITTED's values)."""
        radius = float(self.merge_pixels) * float(np.median(obs["footprint"]))
        parts = [self._object_points(obs, o, radius) for o in np.unique(obs["object"])]
        return parts, self._stored_points(parts, radius)

    def _checked_poses(self, frames, poses) -> np.ndarray:
        return _check_poses(frames, poses, type(self).__name__)

    def _observe(self, frames, poses) -> dict:
        """Keypoints of the used training frames, lifted: per observation xyz, desc
        (uint8), view, object, footprint (metres per pixel); per view its camera and
        small depth map."""
        used = _spread(len(poses), int(self.max_train_frames))
        Rs, ts = label_to_pose(poses[used])
        sift = pts.make_sift(self.max_keypoints)
        cols = {k: [] for k in ("xyz", "desc", "view", "object", "footprint")}
        views = {"depth": [], "shape": [], "K": [], "R": Rs, "t": ts, "object": []}
        for j, i in enumerate(used):
            frame = frames[int(i)]
            _check_keys(frame, TRAIN_KEYS, int(i), "training", type(self).__name__)
            K, depth = np.asarray(frame["K"], dtype=np.float64), np.asarray(frame["depth"], dtype=np.float32)
            obj = int(frame.get("sequence", 0))
            uv, desc = pts.remembered_sift_features(frame["rgb"], frame["mask"], side=self.sift_side,
                                                    max_keypoints=self.max_keypoints, sift=sift)
            xyz, ok = pts.lift(uv, depth, K, Rs[j], ts[j])
            z = (xyz[ok] @ Rs[j].T + ts[j])[:, 2]
            cols["xyz"].append(xyz[ok])
            cols["desc"].append(np.clip(np.rint(desc[ok]), 0, 255).astype(np.uint8))
            cols["view"].append(np.full(ok.sum(), j))
            cols["object"].append(np.full(ok.sum(), obj))
            cols["footprint"].append(z / K[0, 0])
            views["depth"].append(pts.small_depth(depth))
            views["shape"].append(depth.shape)
            views["K"].append(K)
            views["object"].append(obj)
        obs = {k: np.concatenate(v) if v else np.zeros(0) for k, v in cols.items()}
        obs["xyz"] = obs["xyz"].reshape(-1, 3)
        obs["desc"] = obs["desc"].reshape(-1, 128)
        obs["views"] = views
        return obs

    def _object_points(self, obs, obj: int, radius: float) -> dict:
        """One object's 3-D points (seen in at least 2 views): positions (the median of their
        observations), the views that detected them (columns: ``view_ids``, the object's views) and
        stored descriptors (rows of obs: up to ``descriptors_per_point``, spread over each point's
        observations in their order). Array work over every point at once (a loop over points
        was a fifth of N3M's training time), the same numbers as point by point."""
        rows = np.flatnonzero(obs["object"] == obj)
        labels = pts.merge_observations(obs["xyz"][rows], np.zeros(len(rows)), radius)
        view_ids = np.flatnonzero(np.asarray(obs["views"]["object"]) == obj)
        order = np.argsort(labels, kind="stable")
        members, starts = rows[order], np.r_[0, np.flatnonzero(np.diff(labels[order])) + 1, len(order)]
        pairs = np.unique(labels[order] * len(view_ids) + np.searchsorted(view_ids, obs["view"][members]))
        detected = np.zeros((len(starts) - 1, len(view_ids)), dtype=bool)
        detected[pairs // len(view_ids), pairs % len(view_ids)] = True
        keep = np.flatnonzero(detected.sum(axis=1) >= 2)
        position = pts.group_medians(obs["xyz"][members], starts)
        picks = pts.spread_picks(np.diff(starts)[keep], int(self.descriptors_per_point))
        desc_rows = [members[starts[p] + pick] for p, pick in zip(keep, picks)]
        return {"position": position[keep], "detected": detected[keep], "view_ids": view_ids,
                "desc_rows": desc_rows, "object": obj, "desc": obs["desc"]}

    def _stored_points(self, parts, radius: float) -> dict:
        """Every object's points into one database: {attribute of SiftPoints.FITTED: value}."""
        offsets = _offsets(parts)
        points = np.concatenate([p["position"] for p in parts]).reshape(-1, 3)
        owner = [np.full(len(r), offsets[k] + i) for k, p in enumerate(parts) for i, r in enumerate(p["desc_rows"])]
        if len(points) < 4:
            raise ModelError(f"{type(self).__name__}: only {len(points)} 3-D points were seen in 2 or more "
                             "training views; give more (or closer) training views")
        return {"points_": points, "point_object_": np.repeat([p["object"] for p in parts], np.diff(offsets)),
                "descriptors_": np.concatenate([p["desc"][r] for p in parts for r in p["desc_rows"]]),
                "descriptor_point_": np.concatenate(owner), "merge_radius_": radius}

    # ------------------------------------------------------------------ predict
    def predict(self, frames) -> np.ndarray:
        """(n, 6) labels of ``frames`` (keys TEST_KEYS); NaN rows where no pose passes."""
        return self.predict_details(frames)[0]

    def features_found(self, frames) -> np.ndarray:
        """(n,) bool: the frames SIFT found keypoints on (inside the mask; remembered, so after
        predict this costs no SIFT)."""
        sift = pts.make_sift(self.max_keypoints)
        return np.array([len(pts.remembered_sift_features(f["rgb"], f["mask"], side=self.sift_side,
                                                          max_keypoints=self.max_keypoints, sift=sift)[0]) > 0
                         for f in frames], dtype=bool)

    def predict_details(self, frames) -> tuple[np.ndarray, list]:
        """(labels (n, 6), per frame "n3m", "ransac" or None: what gave the pose, a marker
        or PnP with RANSAC over all matches)."""
        self.check_fitted()
        index = self._index()
        sift = pts.make_sift(self.max_keypoints)
        out = np.full((len(frames), 6), np.nan)
        sources = []
        desc_xyz = self.points_[self.descriptor_point_]   # once, not per frame: (d, 3), a gather of every row
        for i, frame in enumerate(frames):
            _check_keys(frame, TEST_KEYS, i, "test", type(self).__name__)
            found = self._predict_one(frame, index, sift, desc_xyz)
            sources.append(None if found is None else found[3])
            if found is not None:
                out[i] = pose_to_label(found[0], found[1])
        return out, sources

    def _predict_one(self, frame, index, sift, desc_xyz):
        uv, desc = pts.remembered_sift_features(frame["rgb"], frame["mask"], side=self.sift_side,
                                                max_keypoints=self.max_keypoints, sift=sift)
        keypoint, point = match(index, desc_xyz, self.descriptor_point_, desc, ratio=float(self.ratio),
                                same_radius=2 * self.merge_radius_)
        return self._pose(point, self.points_[point], uv[keypoint], frame["K"])

    @abstractmethod
    def _pose(self, matched_point, xyz, uv, K):
        """The pose of matches ``xyz`` (m, 3) -> ``uv`` (m, 2) of points ``matched_point`` (m,):
        (R, t, inliers, source) or None (n3m_pose.estimate's)."""

    def _index(self):
        """The FLANN index over the stored descriptors (built once per process for equal ones:
        sift_points_memo), its searches remembered per test image."""
        cached = getattr(self, "_flann", None)
        if cached is None or cached[0] is not self.descriptors_:
            key, index = memo.remembered_index(self.descriptors_, lambda d: pts.build_index(d.astype(np.float32)))
            cached = (self.descriptors_, memo.RememberedSearches(key, index))
            self._flann = cached
        return cached[1]


class N3MPose(SiftPoints):
    """N3M pose estimator. Parameters (keyword-only): those of :class:`SiftPoints`
    (sift_side, max_keypoints, max_train_frames, merge_pixels, descriptors_per_point, ratio,
    reprojection_error, min_inliers), and

    marker_size: points per N3M (at least 4).
    marker_radius: an N3M's points lie within this fraction of its object's extent.
    min_relief: least flatness (smallest / largest singular value) of an N3M.
    per_view: N3Ms each training view should see.
    max_markers: N3Ms per object at most.
    ransac_fallback: when no N3M passes, PnP with RANSAC over all matches proposes. Not in
        the paper; off by default (the paper's method alone). That step on its own, for
        every image, is the SIFT + PnP baseline (sift_pnp.SiftPnPPose).

    Deterministic, no seed (:class:`SiftPoints`).
    """

    FITTED = SiftPoints.FITTED + ("quality_", "markers_")

    def __init__(self, *, sift_side=256, max_keypoints=300, max_train_frames=1500, merge_pixels=1.5,
                 descriptors_per_point=6, ratio=0.8, marker_size=5, marker_radius=0.3, min_relief=0.1,
                 per_view=3, max_markers=150, reprojection_error=3.0, min_inliers=6,
                 ransac_fallback=False):
        super().__init__(sift_side=sift_side, max_keypoints=max_keypoints, max_train_frames=max_train_frames,
                         merge_pixels=merge_pixels, descriptors_per_point=descriptors_per_point, ratio=ratio,
                         reprojection_error=reprojection_error, min_inliers=min_inliers)
        self.marker_size = marker_size
        self.marker_radius = marker_radius
        self.min_relief = min_relief
        self.per_view = per_view
        self.max_markers = max_markers
        self.ransac_fallback = ransac_fallback

    # ------------------------------------------------------------------ fit
    def fit(self, frames, poses) -> "N3MPose":
        """Learn the 3-D points and N3Ms from posed ``frames`` (keys TRAIN_KEYS, and
        "sequence": one id per object/camera path, default 0) and ``poses`` (n, 6)."""
        poses = self._checked_poses(frames, poses)
        if int(self.marker_size) < 4:
            raise ModelError(f"N3MPose: marker_size must be at least 4 (a pose needs 4 points), got {self.marker_size}")
        obs, parts = self._lift_points(frames, poses)
        self._select(obs, parts)
        return self

    def _select(self, obs, parts) -> None:
        """The points' quality (repeatability x distinctiveness) and every object's N3Ms."""
        offsets = _offsets(parts)
        distinct = pts.distinctiveness(self.descriptors_.astype(np.float32), self.points_[self.descriptor_point_],
                                       same_radius=2 * self.merge_radius_, ratio=float(self.ratio))
        n = len(self.points_)
        per_point = np.bincount(self.descriptor_point_, distinct, n) / np.bincount(self.descriptor_point_,
                                                                                    minlength=n)
        quality = np.concatenate([_repeatability(obs, p) for p in parts]) * per_point
        markers = []
        for k, p in enumerate(parts):
            pos = p["position"]
            extent = float(np.linalg.norm(pos.max(axis=0) - pos.min(axis=0))) if len(pos) else 0.0
            found = select_markers(pos, quality[offsets[k]:offsets[k + 1]], p["detected"],
                                   size=int(self.marker_size), radius=float(self.marker_radius) * extent,
                                   min_gap=2 * self.merge_radius_, min_relief=float(self.min_relief),
                                   per_view=int(self.per_view), max_markers=int(self.max_markers))
            markers.append(found + offsets[k])
        self.quality_ = quality
        self.markers_ = np.concatenate(markers).reshape(-1, int(self.marker_size))

    # ------------------------------------------------------------------ predict
    def _pose(self, matched_point, xyz, uv, K):
        return estimate(self.markers_, matched_point, xyz, uv, K, tol=float(self.reprojection_error),
                        min_inliers=int(self.min_inliers), fallback=bool(self.ransac_fallback))


def _repeatability(obs, part) -> np.ndarray:
    """(n,) per point of ``part``: the views that detected it over the views that see it (a
    depth test on the small depth maps; a detection counts as seen)."""
    v, ids = obs["views"], part["view_ids"]
    visible = pts.visibility(part["position"], [v["depth"][i] for i in ids], [v["shape"][i] for i in ids],
                             [v["K"][i] for i in ids], v["R"][ids], v["t"][ids])
    visible |= part["detected"]
    return part["detected"].sum(axis=1) / np.maximum(visible.sum(axis=1), 1)


def _offsets(parts) -> np.ndarray:
    """(objects + 1,) where each object's points start in the database, and their total."""
    return np.cumsum([0] + [len(p["position"]) for p in parts])


def _spread(n: int, most: int) -> np.ndarray:
    """At most ``most`` of ``range(n)``, evenly spaced (every frame when n <= most)."""
    if n <= most or most <= 0:
        return np.arange(n)
    return np.unique(np.rint(np.linspace(0, n - 1, most)).astype(np.int64))


def _check_keys(frame, keys, i: int, kind: str, name: str) -> None:
    """ModelError (from the estimator ``name``) unless ``frame`` has ``keys``, an (H, W, 3)
    rgb and an (H, W) mask."""
    missing = [k for k in keys if k not in frame]
    if missing:
        raise ModelError(f"{name}: {kind} frame {i} has no {', '.join(missing)}; expected keys {list(keys)}")
    rgb, mask = np.shape(frame["rgb"]), np.shape(frame["mask"])
    if len(rgb) != 3 or rgb[2] != 3 or mask != rgb[:2] or np.shape(frame["K"]) != (3, 3):
        raise ModelError(f"{name}: {kind} frame {i} has rgb {rgb}, mask {mask}, K {np.shape(frame['K'])}; "
                         "expected rgb (H, W, 3), mask (H, W) and K (3, 3)")


def _check_poses(frames, poses, name: str) -> np.ndarray:
    poses = np.asarray(poses, dtype=np.float64)
    if poses.ndim != 2 or poses.shape[1] != 6 or len(poses) == 0:
        raise ModelError(f"{name}.fit: poses must be (n, 6) rx, ry, rz degrees and t metres with n >= 1, "
                         f"got shape {poses.shape}")
    if len(frames) != len(poses):
        raise ModelError(f"{name}.fit: {len(frames)} frames but {len(poses)} poses; give one pose per frame")
    if not np.all(np.isfinite(poses)):
        raise ModelError(f"{name}.fit: poses contain NaN or inf; give finite training poses")
    return poses

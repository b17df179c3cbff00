"""SIFT + PnP: N3M's RANSAC fallback on its own, as a baseline; not in any paper (ours).

The same 3-D points as N3M (n3m.SiftPoints: SIFT keypoints of posed training views with
depth, lifted, merged, seen in 2 views or more) and the same matching; then, for every
test image, PnP with RANSAC over all its matches proposes the pose and N3M's global test
accepts it (n3m_pose.ransac_pose: at least ``min_inliers`` matches reproject within
``reprojection_error`` pixels after refinement). No point scores, no markers, no marker
level: what N3M's levels add over plain matching and robust PnP is the difference
between the two rows. docs/method.md, "SIFT + PnP".

Training frames are read for "rgb", "mask", "depth", "K" and (optionally) "sequence";
test frames for "rgb", "mask", "K" only.
"""

from __future__ import annotations

from spm_model.methods.n3m import SiftPoints
from spm_model.methods.n3m_pose import ransac_pose


class SiftPnPPose(SiftPoints):
    """SIFT + PnP pose estimator. Parameters (keyword-only): those of :class:`SiftPoints`
    (sift_side, max_keypoints, max_train_frames, merge_pixels, descriptors_per_point, ratio,
    reprojection_error, min_inliers), N3MPose's of the same names with the same defaults,
    so that the two share their SIFT (remembered per image) and their 3-D points are the
    same. Deterministic, no seed (:class:`SiftPoints`).
    """

    def fit(self, frames, poses) -> "SiftPnPPose":
        """Learn the 3-D points from posed ``frames`` (keys "rgb", "mask", "depth", "K", and
        "sequence": one id per object/camera path, default 0) and ``poses`` (n, 6)."""
        self._lift_points(frames, self._checked_poses(frames, poses))
        return self

    def _pose(self, matched_point, xyz, uv, K):
        return ransac_pose(xyz, uv, K, tol=float(self.reprojection_error), min_inliers=int(self.min_inliers))

"""Frames, camera conventions and the 6-DoF label: the one place they are defined.

Frames
------
* **Object frame**: right-handed, metres, origin at the centre of the mesh's
  bounding box, ``+z`` up, the object's front towards ``+x`` (meshes.py
  normalises every mesh into it).
* **Camera frame (OpenCV)**: ``x`` right, ``y`` down, ``z`` forward along the
  optical axis, metres. Every pose stored in a shard is in this convention.
* **OpenGL / Blender camera**: ``x`` right, ``y`` up, looking down ``-z``. The
  two differ by ``diag(1, -1, -1)``; renderers convert at their boundary with
  :func:`cv_to_gl_camera_to_world` and nowhere else.

Pose
----
``R`` (3, 3) and ``t`` (3,) map object to camera: ``X_cam = R @ X_obj + t``.
The object origin projects to ``K @ t``.

Camera path point
-----------------
``(azimuth, elevation, roll, distance, look_at)``: the camera centre is at
``look_at + distance * (cos el cos az, cos el sin az, sin el)`` in the object
frame, looks at ``look_at``, keeps the object's ``+z`` up in the image (camera
``x`` is ``(-sin az, cos az, 0)``), then rolls by ``roll`` about its optical
axis (positive roll turns the camera's ``x`` towards its ``y``). Angles in
degrees, distance in metres.

Label
-----
``y = (rx, ry, rz, tx, ty, tz)``: ``R = Rx(rx) @ Ry(ry) @ Rz(rz)`` (intrinsic
X-Y-Z Euler angles, scipy's ``"XYZ"``), degrees wrapped to ``(-180, 180]``;
``t`` in metres. On the default paths (roll 0) this reads
``rx = 90 + elevation``, ``ry = 0``, ``rz = -(azimuth + 90)``, and it is singular
only at ``|sin(roll) cos(elevation)| = 1``, far from any default path.

Pixels
------
``K`` follows OpenCV: the centre of pixel ``(col, row)`` is at ``u = col``,
``v = row``; a centred camera has ``cx = (W - 1) / 2``. BOP, pyrender's
``IntrinsicsCamera`` and Blender count from the pixel's corner instead (the
centre of pixel ``(col, row)`` at ``u = col + 0.5``; a centred camera has
``cx = W / 2``): :func:`K_to_corner_origin` and :func:`K_from_corner_origin`
convert, at the boundary (the renderers, BOP export and import), and nowhere else.

glTF
----
glTF files are ``+y`` up with the front towards ``+z``; :data:`GLTF_TO_OBJECT`
turns them into the object frame (``+z`` up, front ``+x``) as they are loaded.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from spm_data.errors import SpmError

EULER_ORDER = "XYZ"  # scipy: upper case = intrinsic rotations
CV_TO_GL = np.diag([1.0, -1.0, -1.0])
# glTF (x, y, z) -> object frame (z_gltf, x_gltf, y_gltf): +y up becomes +z up and the
# glTF front (+z) becomes ours (+x); a rotation (det +1), so no mesh is mirrored.
GLTF_TO_OBJECT = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
PIXEL_CORNER_SHIFT = 0.5  # pixels from OpenCV's principal point to a corner-origin one


def camera_poses(azimuth, elevation, roll, distance, look_at=(0.0, 0.0, 0.0)):
    """Object->camera poses for camera path points.

    azimuth, elevation, roll: (N,) or scalar, degrees. distance: (N,) or scalar,
    metres, > 0. look_at: (3,) or (N, 3), metres, object frame.
    Returns ``R`` (N, 3, 3) float64 and ``t`` (N, 3) float64, OpenCV camera frame.
    """
    az, el, rl, d = np.broadcast_arrays(*(np.atleast_1d(np.asarray(a, dtype=np.float64))
                                          for a in (azimuth, elevation, roll, distance)))
    if np.any(d <= 0):
        raise SpmError(f"camera distance must be > 0 metres, got {float(d.min())}")
    if np.any(np.abs(el) > 90):
        raise SpmError(f"elevation must lie in [-90, 90] degrees, got {float(np.abs(el).max())}")
    n = az.shape[0]
    target = np.broadcast_to(np.asarray(look_at, dtype=np.float64), (n, 3))
    a, e, r = np.radians(az), np.radians(el), np.radians(rl)
    direction = np.stack([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)], axis=1)
    centre = target + d[:, None] * direction
    forward = -direction
    # The limit of forward x up as elevation -> 90: never singular on [-90, 90].
    right = np.stack([-np.sin(a), np.cos(a), np.zeros(n)], axis=1)
    down = np.cross(forward, right)
    c, s = np.cos(r)[:, None], np.sin(r)[:, None]
    right, down = c * right + s * down, -s * right + c * down
    R = np.stack([right, down, forward], axis=1)  # rows: camera axes in object frame
    t = -np.einsum("nij,nj->ni", R, centre)
    return R, t


def camera_pose(azimuth, elevation, roll, distance, look_at=(0.0, 0.0, 0.0)):
    """One path point -> ``R`` (3, 3), ``t`` (3,) (see :func:`camera_poses`)."""
    R, t = camera_poses(azimuth, elevation, roll, distance, look_at)
    return R[0], t[0]


def wrap_degrees(angles):
    """Wrap angles in degrees to (-180, 180]."""
    wrapped = np.mod(np.asarray(angles, dtype=np.float64) + 180.0, 360.0) - 180.0
    return np.where(wrapped == -180.0, 180.0, wrapped)


def pose_to_label(R, t):
    """``R`` (N, 3, 3) or (3, 3), ``t`` (N, 3) or (3,) -> label (N, 6) or (6,) float64.

    ``(rx, ry, rz)`` degrees (intrinsic XYZ, wrapped to (-180, 180]), ``(tx, ty, tz)`` metres.
    """
    R = np.asarray(R, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64)
    single = R.ndim == 2
    angles = Rotation.from_matrix(R.reshape(-1, 3, 3)).as_euler(EULER_ORDER, degrees=True)
    label = np.concatenate([wrap_degrees(angles), t.reshape(-1, 3)], axis=1)
    return label[0] if single else label


def label_to_pose(label):
    """label (N, 6) or (6,) -> ``R`` (N, 3, 3) / (3, 3), ``t`` (N, 3) / (3,)."""
    label = np.asarray(label, dtype=np.float64)
    single = label.ndim == 1
    label = label.reshape(-1, 6)
    R = Rotation.from_euler(EULER_ORDER, label[:, :3], degrees=True).as_matrix()
    t = label[:, 3:].copy()
    return (R[0], t[0]) if single else (R, t)


def label_to_view(label):
    """label (N, 6) or (6,) -> the camera path point it was seen from, assuming
    the camera looks at the object origin (every default path does).

    Returns a dict of (N,) float64 arrays (scalars for one label): ``azimuth``
    (-180, 180] and ``elevation`` [-90, 90] of the camera centre in the object
    frame, ``roll`` (-180, 180] about the optical axis (0 keeps the object's +z
    up in the image), all degrees; ``distance``, metres from the object origin
    to the camera centre. The inverse of :func:`camera_poses` for ``look_at = 0``.
    """
    label = np.asarray(label, dtype=np.float64)
    single = label.ndim == 1
    R, t = label_to_pose(label.reshape(-1, 6))
    centre = -np.einsum("nji,nj->ni", R, t)             # camera centre, object frame
    distance = np.linalg.norm(centre, axis=1)
    direction = centre / np.maximum(distance, 1e-300)[:, None]
    azimuth = wrap_degrees(np.degrees(np.arctan2(direction[:, 1], direction[:, 0])))
    elevation = np.degrees(np.arcsin(np.clip(direction[:, 2], -1.0, 1.0)))
    # Roll: the angle from the unrolled camera x, (-sin az, cos az, 0), to the actual one.
    a = np.radians(azimuth)
    right = np.stack([-np.sin(a), np.cos(a), np.zeros_like(a)], axis=1)
    down = np.cross(-direction, right)
    roll = wrap_degrees(np.degrees(np.arctan2(np.einsum("ni,ni->n", R[:, 0], down),
                                              np.einsum("ni,ni->n", R[:, 0], right))))
    view = {"azimuth": azimuth, "elevation": elevation, "roll": roll, "distance": distance}
    return {k: float(v[0]) for k, v in view.items()} if single else view


# What a rotation is, for every importer and for validate (one place). An input matrix
# (a capture's, a table's, a BOP file's) within ROTATION_TOLERANCE of orthonormal with
# determinant +1 is taken as the rotation nearest to it (nearest_rotation, by SVD) and stored so;
# one further off is refused. A stored R must be a rotation to STORED_ROTATION_TOLERANCE
# (float64 round-off, with margin): what validate checks, and what nearest_rotation gives.
ROTATION_TOLERANCE = 1e-4
STORED_ROTATION_TOLERANCE = 1e-6
# An absurd value is refused on import (no capture is a million metres or pixels across).
MAX_DISTANCE_M = 1e6
MAX_FOCAL_PX = 1e7


def rotation_error(R) -> np.ndarray:
    """How far ``R`` (..., 3, 3) is from a rotation: the largest of ``|R R^T - I|`` and
    ``|det R - 1|``, per matrix ((...,) float64; inf for a non-finite matrix)."""
    R = np.asarray(R, dtype=np.float64)
    with np.errstate(invalid="ignore", over="ignore"):
        ortho = np.abs(R @ np.swapaxes(R, -1, -2) - np.eye(3)).max(axis=(-2, -1))
        error = np.maximum(ortho, np.abs(np.linalg.det(R) - 1.0))
    return np.where(np.isfinite(error), error, np.inf)


def is_rotation(R, atol: float = ROTATION_TOLERANCE) -> bool:
    """Whether ``R`` (3, 3) is a rotation: orthonormal within ``atol``, determinant +1."""
    return bool(rotation_error(np.asarray(R, dtype=np.float64).reshape(3, 3)) <= atol)


def nearest_rotation(R) -> np.ndarray:
    """The rotation nearest ``R`` (3, 3) in the Frobenius norm (SVD: ``U V^T``, the sign of
    the last singular vector flipped when the determinant would be -1); (3, 3) float64."""
    U, _, Vt = np.linalg.svd(np.asarray(R, dtype=np.float64).reshape(3, 3))
    if np.linalg.det(U @ Vt) < 0:
        U[:, -1] = -U[:, -1]
    return U @ Vt


def intrinsics_from_fov(fov_y_deg, width, height):
    """Pinhole ``K`` (3, 3) float64 with square pixels and a centred principal point.

    fov_y_deg: vertical field of view in degrees, in (0, 180). OpenCV pixel centres.
    """
    if not 0 < fov_y_deg < 180:
        raise SpmError(f"field of view must be in (0, 180) degrees, got {fov_y_deg}")
    f = (height / 2.0) / np.tan(np.radians(fov_y_deg) / 2.0)
    return np.array([[f, 0.0, (width - 1) / 2.0], [0.0, f, (height - 1) / 2.0], [0.0, 0.0, 1.0]])


def K_to_corner_origin(K) -> np.ndarray:
    """OpenCV ``K`` (3, 3) -> the same camera with pixel-corner origin (BOP, pyrender,
    Blender): ``cx + 0.5``, ``cy + 0.5``; a (3, 3) float64 copy."""
    out = np.array(K, dtype=np.float64).reshape(3, 3)
    out[:2, 2] += PIXEL_CORNER_SHIFT
    return out


def K_from_corner_origin(K) -> np.ndarray:
    """Inverse of :func:`K_to_corner_origin`: ``cx - 0.5``, ``cy - 0.5``; (3, 3) float64."""
    out = np.array(K, dtype=np.float64).reshape(3, 3)
    out[:2, 2] -= PIXEL_CORNER_SHIFT
    return out


def scale_K(K, sx: float, sy: float) -> np.ndarray:
    """OpenCV ``K`` (3, 3) of an image resized by ``sx`` (new width / old width) and ``sy``: the
    image's extent maps onto the new one, so a pixel centre ``u`` goes to ``(u + 0.5) sx - 0.5``
    (``fx sx``, ``(cx + 0.5) sx - 0.5``; the same in y). (3, 3) float64."""
    K = np.array(K, dtype=np.float64).reshape(3, 3)
    S = np.array([[sx, 0.0, PIXEL_CORNER_SHIFT * (sx - 1)], [0.0, sy, PIXEL_CORNER_SHIFT * (sy - 1)], [0, 0, 1.0]])
    return S @ K


def project_points(points, K, R, t):
    """Project object-frame points into the image.

    points: (N, 3) metres, object frame. Returns ``uv`` (N, 2) float64 pixels
    (OpenCV centres) and ``z`` (N,) metres, depth along the camera's z axis.
    """
    cam = np.asarray(points, dtype=np.float64) @ np.asarray(R).T + np.asarray(t)
    z = cam[:, 2]
    uvw = cam @ np.asarray(K).T
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = uvw[:, :2] / uvw[:, 2:3]
    return uv, z


def cv_to_gl_camera_to_world(R, t):
    """OpenCV object->camera ``R, t`` -> (4, 4) camera->object matrix in the
    OpenGL / Blender camera convention (pyrender's camera pose, Blender's
    ``camera.matrix_world`` when the object sits at the world origin)."""
    R = np.asarray(R, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64)
    M = np.eye(4)
    M[:3, :3] = R.T @ CV_TO_GL
    M[:3, 3] = -R.T @ t
    return M


def gl_camera_to_world_to_cv(M):
    """Inverse of :func:`cv_to_gl_camera_to_world`: (4, 4) -> ``R`` (3, 3), ``t`` (3,)."""
    M = np.asarray(M, dtype=np.float64)
    R = (M[:3, :3] @ CV_TO_GL).T
    t = -R @ M[:3, 3]
    return R, t


def gl_camera_to_world_to_object(M, scale: float = 1.0, center=(0.0, 0.0, 0.0), where: str = "the pose"):
    """A capture's camera: (4, 4) camera->world ``M`` in the OpenGL camera convention (what
    instant-ngp's and nerfstudio's ``transform_matrix`` hold), world in the capture's units ->
    ``R`` (3, 3), ``t`` (3,) metres, object -> OpenCV camera, where the object frame is the world
    frame moved to ``center`` (3,) (world units) and scaled by ``scale`` (metres per world unit):
    ``X_obj = scale * (X_world - center)``. SpmError naming ``where`` when ``M``'s rotation part
    is not a rotation (a scaled or mirrored matrix) or its last row is not (0, 0, 0, 1)."""
    M = np.array(M, dtype=np.float64).reshape(4, 4)
    if not np.allclose(M[3], [0.0, 0.0, 0.0, 1.0]):
        raise SpmError(f"{where}: transform_matrix's last row is {M[3].tolist()}; expected [0, 0, 0, 1]")
    if not is_rotation(M[:3, :3]):
        raise SpmError(f"{where}: transform_matrix's 3x3 part is not a rotation (orthonormal, determinant +1); "
                       "rescale the capture with --scale instead of inside the matrices")
    M[:3, 3] = scale * (M[:3, 3] - np.asarray(center, dtype=np.float64))
    return gl_camera_to_world_to_cv(M)

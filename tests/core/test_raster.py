"""Silhouettes at pixel centres, and object coordinates from depth."""

import numpy as np
import pytest

from spm_data.core.instances import load_instance
from spm_data.core.paths import camera_path
from spm_data.core.raster import object_coords, silhouette
from spm_data.core.specs import parse_spec
from spm_data.errors import SpmError

UNIT_K = np.eye(3)


def square(x0, x1, y0, y1, z=1.0):
    vertices = np.array([[x0, y0, z], [x1, y0, z], [x1, y1, z], [x0, y1, z]], float)
    return vertices, np.array([[0, 1, 2], [0, 2, 3]])


def test_a_square_covers_exactly_the_pixel_centres_inside_it():
    v, f = square(1.5, 4.5, 0.5, 2.5)
    mask = silhouette(v, f, UNIT_K, np.eye(3), np.zeros(3), 5, 6)
    expected = np.zeros((5, 6), bool)
    expected[1:3, 2:5] = True  # rows 1..2, columns 2..4
    np.testing.assert_array_equal(mask, expected)


def test_both_windings_count_and_a_centre_on_an_edge_is_covered():
    v, f = square(1.0, 3.0, 1.0, 3.0)
    a = silhouette(v, f, UNIT_K, np.eye(3), np.zeros(3), 5, 5)
    b = silhouette(v, f[:, ::-1], UNIT_K, np.eye(3), np.zeros(3), 5, 5)
    np.testing.assert_array_equal(a, b)
    assert a[1:4, 1:4].all() and a.sum() == 9


def test_a_mesh_reaching_behind_the_camera_is_refused():
    v, f = square(-1, 1, -1, 1, z=-0.5)
    with pytest.raises(SpmError, match="behind the camera"):
        silhouette(v, f, UNIT_K, np.eye(3), np.zeros(3), 4, 4)


@pytest.mark.parametrize("cls", ["box", "motorcycle", "cup"])
def test_silhouettes_match_pyrender_masks_to_a_pixel_or_two(cls):
    from spm_data.render import make_renderer
    from spm_data.render.base import spec_intrinsics

    spec = parse_spec(f'class = "{cls}"\n[render]\nrenderer = "pyrender"')
    renderer = make_renderer(spec)
    mesh = load_instance(spec, 1)
    renderer.set_mesh(mesh)
    R, t = camera_path(spec.camera).poses(np.arange(0, 900, 61))
    for i in range(len(R)):
        mask = renderer.render(R[i], t[i])["mask"] > 0
        ours = silhouette(mesh.vertices, mesh.faces, spec_intrinsics(spec), R[i], t[i], 128, 128)
        assert mask.sum() > 500
        assert (ours != mask).sum() <= 3, (cls, i)


def test_object_coords_back_project_depth_into_the_object_frame():
    K = np.array([[100.0, 0, 4.0], [0, 100.0, 3.0], [0, 0, 1]])
    depth = np.full((7, 9), 2.0)
    mask = np.zeros((7, 9), bool)
    mask[3, 4] = mask[3, 8] = True
    R = np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]])  # object x is camera y
    t = np.array([0.0, 0.0, 1.5])
    coords = object_coords(depth, mask, K, R, t)
    np.testing.assert_allclose(coords[3, 4], [0.0, 0.0, 0.5])          # the principal point, 2 m away
    np.testing.assert_allclose(coords[3, 8], [0.0, -0.08, 0.5])        # 4 px right = 0.08 m along camera x
    assert not coords[~mask].any()

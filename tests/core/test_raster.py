"""Silhouettes and depth by the rules of bop_toolkit's vispy renderer on llvmpipe (checked against
numbers it gave, bop_toolkit cea62d6, Mesa 22.3.6), and object coordinates from depth."""

import zlib

import numpy as np
import pytest
import trimesh

from spm_data.core.instances import load_instance
from spm_data.core.paths import camera_path
from spm_data.core.raster import object_coords, render_depth, silhouette
from spm_data.core.shapes import procedural_mesh
from spm_data.core.specs import parse_spec
from spm_data.errors import SpmError
from spm_data.formats.bop.gt import bbox

UNIT_K = np.eye(3)
CUBE = trimesh.creation.box(extents=(100.0, 100.0, 100.0))   # mm, centred


def square(x0, x1, y0, y1, z=1.0):
    vertices = np.array([[x0, y0, z], [x1, y0, z], [x1, y1, z], [x0, y1, z]], float)
    return vertices, np.array([[0, 1, 2], [0, 2, 3]])


def test_a_square_covers_exactly_the_pixel_centres_inside_it():
    # Flat and facing the camera: vispy's near and far planes would meet; they are set apart.
    v, f = square(1.5, 4.5, 0.5, 2.5)
    mask = silhouette(v, f, UNIT_K, np.eye(3), np.zeros(3), 5, 6)
    expected = np.zeros((5, 6), bool)
    expected[1:3, 2:5] = True  # rows 1..2, columns 2..4
    np.testing.assert_array_equal(mask, expected)


def test_both_windings_count_and_a_centre_on_an_edge_follows_the_fill_rule():
    # Pixel centres on all four edges: the left and bottom edges' are in, the right and top edges' out.
    v, f = square(1.0, 3.0, 1.0, 3.0)
    a = silhouette(v, f, UNIT_K, np.eye(3), np.zeros(3), 5, 5)
    b = silhouette(v, f[:, ::-1], UNIT_K, np.eye(3), np.zeros(3), 5, 5)
    np.testing.assert_array_equal(a, b)
    assert a[2:4, 1:3].all() and a.sum() == 4


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


def test_a_cube_with_edges_on_pixel_centres_keeps_its_left_and_bottom_edges():
    # 100 mm cube, 500 mm away, f = 90: its front face spans u, v = c ± 10, on pixel centres when c
    # ends in .5 (BOP's pixel-corner convention). vispy on llvmpipe gave 20 x 20 = 400 pixels:
    # columns 22-41 (left edge in, right out), rows 15-34 (top edge out, bottom in).
    K = np.array([[90.0, 0, 32.5], [0, 90.0, 24.5], [0, 0, 1]])
    depth = render_depth(np.float32(CUBE.vertices), CUBE.faces, K, np.eye(3), [0, 0, 500.0], 64, 48)
    ys, xs = np.nonzero(depth)
    assert len(ys) == 400 and (ys.min(), ys.max(), xs.min(), xs.max()) == (15, 34, 22, 41)
    np.testing.assert_allclose(depth[depth > 0], 450.0, atol=1e-3)
    K_centres = np.array([[90.0, 0, 32.0], [0, 90.0, 24.0], [0, 0, 1]])   # OpenCV's convention, metres
    ours = silhouette(CUBE.vertices / 1000.0, CUBE.faces, K_centres, np.eye(3), [0, 0, 0.5], 48, 64)
    np.testing.assert_array_equal(ours, depth > 0)


# A cup cut by the bottom border, where a plain pixel-centre test (the silhouette before it followed
# these rules) missed two pixels: vispy's counts, boxes and masks (CRC-32 of np.packbits) at image
# size and on calc_gt_info's 3x canvas.
CUT_R = [[-0.043327954052944276, 0.6688054544906514, 0.7421738020444667],
         [0.25527592191399145, -0.7108004171543264, 0.6554364734008913],
         [0.9658969365768523, 0.21785782294145106, -0.13993240116093084]]
CUT_T = [-43.98533568986429, 91.14157162694356, 508.8466999726777]
CUT_K = [[53.88050952014089, 0.0, 31.561835655190887], [0.0, 53.88050952014089, 25.191735544388084], [0.0, 0.0, 1.0]]


@pytest.mark.parametrize("canvas, pixels, box, crc", [
    (1, 506, [8, 17, 32, 30], 2465547510),
    (3, 512, [8, 17, 32, 32], 626360992),
])
def test_a_cup_cut_by_the_border_is_drawn_as_vispy_draws_it(canvas, pixels, box, crc):
    mesh = procedural_mesh("cup", 0, seed=3)
    w, h = 64, 48
    off = (w, h) if canvas == 3 else (0, 0)
    depth = render_depth(np.float32(mesh.vertices * 1000.0), mesh.faces, np.array(CUT_K), np.array(CUT_R),
                         np.array(CUT_T),
                         canvas * w, canvas * h, offset=off)
    assert (depth > 0).sum() == pixels and bbox(depth > 0, offset=off) == box
    assert zlib.crc32(np.packbits(depth > 0).tobytes()) == crc
    K = np.array(CUT_K) + [[0, 0, off[0] - 0.5], [0, 0, off[1] - 0.5], [0, 0, 0]]   # OpenCV centres
    ours = silhouette(mesh.vertices, mesh.faces, K, np.array(CUT_R), np.array(CUT_T) / 1000.0, canvas * h, canvas * w)
    np.testing.assert_array_equal(ours, depth > 0)


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

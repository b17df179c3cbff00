"""spm_data.render.base: the Renderer interface and what the backends share (intrinsics from the
spec, lights around the camera, masks from depth)."""

import numpy as np
import pytest

from spm_data.core.poses import intrinsics_from_fov
from spm_data.core.specs import parse_spec
from spm_data.render.base import Renderer, light_rotations, mask_from_depth, spec_intrinsics

SPEC = 'class = "cup"\n[image]\nwidth = 64\nheight = 48\nfov = 40\n[render]\nrenderer = "pyrender"\n'


def test_spec_intrinsics_are_the_specs_field_of_view_at_pixel_centres():
    spec = parse_spec(SPEC)
    K = spec_intrinsics(spec)
    np.testing.assert_array_equal(K, intrinsics_from_fov(40, 64, 48))
    assert (K[0, 2], K[1, 2]) == (31.5, 23.5) and K.dtype == np.float64


def test_a_renderer_must_implement_the_interface_and_closes_as_a_context_manager():
    class Half(Renderer):
        def version(self):
            return "half 0"

    with pytest.raises(TypeError, match="abstract"):
        Half(parse_spec(SPEC))

    class Null(Half):
        closed = 0

        def settings(self):
            return {}

        def set_mesh(self, mesh):
            pass

        def render(self, R, t):
            return {}

        def close(self):
            Null.closed += 1

    with Null(parse_spec(SPEC)) as r:
        assert r.K.shape == (3, 3)
    assert Null.closed == 1


def test_lights_are_a_head_light_and_a_40_degree_cone_around_it():
    assert len(light_rotations(0)) == 0
    (head,) = light_rotations(1)
    np.testing.assert_array_equal(head, np.eye(3))
    rots = light_rotations(4)
    np.testing.assert_array_equal(rots[0], np.eye(3))
    for R in rots:
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(R) == pytest.approx(1.0)
    directions = np.array([R @ [0, 0, 1.0] for R in rots[1:]])
    np.testing.assert_allclose(np.degrees(np.arccos(directions[:, 2])), 40.0)          # 40 degrees off the axis
    azimuths = np.degrees(np.arctan2(directions[:, 1], directions[:, 0])) % 360
    np.testing.assert_allclose(np.sort(np.diff(np.sort(azimuths))), [120.0, 120.0])    # spread evenly around it


def test_mask_from_depth():
    depth = np.array([[0.0, 0.5], [1e-9, -0.0]], np.float32)
    mask = mask_from_depth(depth)
    assert mask.dtype == np.uint8 and mask.tolist() == [[0, 1], [1, 0]]

import numpy as np
import trimesh

from spm_data.core.meshes import to_textured
from spm_data.core.shapes import procedural_mesh


def test_ball_normals_are_smooth_and_box_edges_stay_sharp():
    ball = procedural_mesh("ball", 0)
    radial = ball.vertices / np.linalg.norm(ball.vertices, axis=1, keepdims=True)
    # Smooth shading: corner normals close to the radial direction, not the facet normal.
    assert np.median(np.sum(radial * ball.normals, axis=1)) > 0.99
    box = to_textured(trimesh.creation.box(extents=(1, 2, 3)), "b", 0.25, np.random.default_rng(0))
    np.testing.assert_allclose(np.abs(box.normals).max(axis=1), 1.0, atol=1e-12)

import numpy as np
import pytest
import trimesh

from spm_data.core.shapes import CLASSES, procedural_mesh


@pytest.mark.parametrize("cls", CLASSES)
def test_procedural_meshes_are_normalised_textured_and_seeded(cls):
    a = procedural_mesh(cls, 0, seed=5, size=0.25)
    again = procedural_mesh(cls, 0, seed=5, size=0.25)
    other = procedural_mesh(cls, 1, seed=5, size=0.25)
    assert np.isclose(a.extents.max(), 0.25)
    lo, hi = a.vertices.min(axis=0), a.vertices.max(axis=0)
    np.testing.assert_allclose((lo + hi) / 2, 0, atol=1e-9)
    assert a.uv.shape == (len(a.vertices), 2) and a.uv.min() >= 0 and a.uv.max() <= 1
    assert a.texture.dtype == np.uint8 and a.texture.shape[2] == 3 and a.texture.std() > 20
    np.testing.assert_allclose(np.linalg.norm(a.normals, axis=1), 1, atol=1e-6)
    np.testing.assert_array_equal(a.vertices, again.vertices)
    np.testing.assert_array_equal(a.texture, again.texture)
    # Instances differ in shape, not only in texture.
    assert a.vertices.shape != other.vertices.shape or not np.allclose(a.vertices, other.vertices)


# --------------------------------------------------------------------------- symmetries and glTF axes

def _surface_gap(mesh, R, seed=0) -> float:
    """Largest distance (as a fraction of the longest side) from the mesh's surface,
    rotated by R (3, 3), back to the unrotated surface: 0 for a symmetry."""
    from scipy.spatial import cKDTree

    tm = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False)
    dense, _ = trimesh.sample.sample_surface(tm, 300_000, seed=seed)
    probe, _ = trimesh.sample.sample_surface(tm, 3_000, seed=seed + 1)
    return float(cKDTree(dense).query(probe @ np.asarray(R).T)[0].max() / mesh.extents.max())


def _box_with(lid_or_handle: bool):
    for i in range(20):
        mesh = procedural_mesh("box", i)
        if (len(mesh.symmetries.discrete) == 1) == lid_or_handle:
            return mesh
    raise AssertionError("no such box in 20 instances")


@pytest.mark.parametrize("lid_or_handle", [True, False])
def test_box_symmetries_map_the_surface_onto_itself(lid_or_handle):
    from spm_data.core.symmetries import rotation

    box = _box_with(lid_or_handle)
    turns = box.symmetries.discrete
    assert len(turns) == (1 if lid_or_handle else 3) and not box.symmetries.continuous
    for R in turns:
        assert _surface_gap(box, R) < 0.01
    # A quarter turn (its sides differ) and, with a lid or handle, turning it over are not.
    assert _surface_gap(box, rotation([0, 0, 1], 90)) > 0.05
    if lid_or_handle:
        assert _surface_gap(box, rotation([1, 0, 0], 180)) > 0.05


def test_ball_is_symmetric_about_z_at_every_angle_and_turned_over():
    from spm_data.core.symmetries import rotation

    ball = min((procedural_mesh("ball", i) for i in range(8)), key=lambda m: m.extents[2] / m.extents[0])
    assert ball.extents[2] < 0.92 * ball.extents[0]   # the flattest of 8: clearly a spheroid
    (axis,), (flip,) = ball.symmetries.continuous, ball.symmetries.discrete
    np.testing.assert_array_equal(axis, [0, 0, 1])
    for degrees in (17.0, 90.0, 233.0):
        assert _surface_gap(ball, rotation(axis, degrees)) < 0.01
    assert _surface_gap(ball, flip) < 0.01
    assert _surface_gap(ball, rotation([1, 0, 0], 90)) > 0.03   # a spheroid, not a sphere


def test_asymmetric_classes_declare_no_symmetry():
    from spm_data.core.symmetries import rotation

    for cls in ("car", "motorcycle", "animal4", "cup"):
        mesh = procedural_mesh(cls, 0)
        assert mesh.symmetries.discrete == () and mesh.symmetries.continuous == ()
        assert _surface_gap(mesh, rotation([0, 0, 1], 180)) > 0.05

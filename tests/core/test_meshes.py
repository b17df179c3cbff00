import numpy as np
import pytest
import trimesh
from PIL import Image

from spm_data.errors import MeshError
from spm_data.core.meshes import CLASSES, load_mesh_file, procedural_mesh, to_textured


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


def test_ball_normals_are_smooth_and_box_edges_stay_sharp():
    ball = procedural_mesh("ball", 0)
    radial = ball.vertices / np.linalg.norm(ball.vertices, axis=1, keepdims=True)
    # Smooth shading: corner normals close to the radial direction, not the facet normal.
    assert np.median(np.sum(radial * ball.normals, axis=1)) > 0.99
    box = to_textured(trimesh.creation.box(extents=(1, 2, 3)), "b", 0.25, np.random.default_rng(0))
    np.testing.assert_allclose(np.abs(box.normals).max(axis=1), 1.0, atol=1e-12)


def _textured_box(offset, colour):
    m = trimesh.creation.box(extents=(1, 1, 1))
    m.apply_translation(offset)
    uv = np.random.default_rng(0).random((len(m.vertices), 2))
    img = Image.fromarray(np.full((8, 8, 3), colour, np.uint8))
    m.visual = trimesh.visual.TextureVisuals(uv=uv, image=img)
    return m


@pytest.mark.parametrize("suffix", [".obj", ".ply", ".stl", ".off", ".glb"])
def test_user_meshes_load_centred_and_scaled(tmp_path, suffix):
    m = trimesh.creation.annulus(r_min=0.5, r_max=1.0, height=0.3)  # not a box, offset and large
    m.apply_scale(1000.0)
    m.apply_translation([5000, -200, 30])
    path = tmp_path / f"ring{suffix}"
    m.export(path)
    mesh = load_mesh_file(path, size=0.3)
    assert np.isclose(mesh.extents.max(), 0.3)
    lo, hi = mesh.vertices.min(axis=0), mesh.vertices.max(axis=0)
    np.testing.assert_allclose((lo + hi) / 2, 0, atol=1e-6)
    assert mesh.texture.std() > 20  # no texture in the file: a procedural one


def test_tiny_meshes_are_normalised_not_rejected(tmp_path):
    m = trimesh.creation.icosphere()
    m.apply_scale(1e-6)
    m.export(tmp_path / "tiny.ply")
    assert np.isclose(load_mesh_file(tmp_path / "tiny.ply", size=0.2).extents.max(), 0.2)


def test_multi_part_textured_glb_keeps_its_texture(tmp_path):
    scene = trimesh.Scene([_textured_box([0, 0, 0], (200, 30, 30)), _textured_box([2, 0, 0], (200, 30, 30))])
    path = tmp_path / "parts.glb"
    scene.export(path)
    mesh = load_mesh_file(path, size=0.25)
    assert len(mesh.faces) == 24
    assert np.isclose(mesh.extents.max(), 0.25)
    np.testing.assert_allclose(mesh.texture.reshape(-1, 3).mean(axis=0), (200, 30, 30), atol=2)
    procedural = load_mesh_file(path, size=0.25, texture="procedural")
    assert procedural.texture.std() > 20


def test_non_watertight_mesh_loads(tmp_path):
    m = trimesh.creation.box()
    m.update_faces(np.arange(len(m.faces)) != 0)
    assert not m.is_watertight
    m.export(tmp_path / "open.obj")
    assert len(load_mesh_file(tmp_path / "open.obj").faces) == 11


@pytest.mark.parametrize("name, content, message", [
    ("empty.obj", b"", "file is empty"),
    ("garbage.ply", b"\x00\x01 this is not a ply file at all", "not a readable mesh"),
    ("points.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\n", "no faces"),
    ("model.xyz", b"1 2 3", "unsupported mesh type"),
])
def test_bad_mesh_files_give_clear_errors(tmp_path, name, content, message):
    (tmp_path / name).write_bytes(content)
    with pytest.raises(MeshError, match=message):
        load_mesh_file(tmp_path / name)


def test_missing_mesh_file(tmp_path):
    with pytest.raises(MeshError, match="not found"):
        load_mesh_file(tmp_path / "nope.obj")


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


def test_gltf_meshes_are_turned_to_z_up_and_front_x(tmp_path):
    # A glTF box: 0.4 tall along glTF's up (+y), 0.2 deep along its front (+z), 0.1 wide (x).
    trimesh.creation.box(extents=(0.1, 0.4, 0.2)).export(tmp_path / "tall.glb")
    trimesh.creation.box(extents=(0.1, 0.4, 0.2)).export(tmp_path / "tall.obj")
    gltf = load_mesh_file(tmp_path / "tall.glb", size=0.4)
    np.testing.assert_allclose(gltf.extents, [0.2, 0.1, 0.4], atol=1e-9)   # front x, width y, up z
    other = load_mesh_file(tmp_path / "tall.obj", size=0.4)
    np.testing.assert_allclose(other.extents, [0.1, 0.4, 0.2], atol=1e-9)  # other formats as they are


def test_gltf_box_stands_upright_at_elevation_zero(tmp_path):
    from spm_data.core.poses import camera_pose
    from spm_data.render import make_renderer
    from spm_data.core.specs import parse_spec

    trimesh.creation.box(extents=(0.1, 0.4, 0.1)).export(tmp_path / "tall.glb")
    spec = parse_spec('class = "t"\n[mesh]\nsource = "files"\nfiles = ["tall.glb"]\n'
                      '[image]\nwidth = 64\nheight = 64\n[render]\nrenderer = "pyrender"\n', base_dir=str(tmp_path))
    renderer = make_renderer(spec)
    renderer.set_mesh(load_mesh_file(tmp_path / "tall.glb", size=0.25))
    mask = renderer.render(*camera_pose(30.0, 0.0, 0.0, 0.8))["mask"] > 0
    rows, cols = np.nonzero(mask)
    height, width = np.ptp(rows) + 1, np.ptp(cols) + 1
    assert height > 2.5 * width   # standing, not lying on its side

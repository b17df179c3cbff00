import numpy as np
import pytest
import trimesh
from PIL import Image

from spm_data.errors import MeshError
from spm_data.meshes import CLASSES, load_mesh_file, procedural_mesh, to_textured


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

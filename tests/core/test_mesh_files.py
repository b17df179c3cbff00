import numpy as np
import pytest
import trimesh
from PIL import Image

from spm_data.errors import MeshError
from spm_data.core.mesh_files import load_mesh_file


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
    ("header.ply", b"ply\n", r"header.ply: not a readable mesh; trimesh could not parse it as .ply"),
    ("faces.ply", b"ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\n"
                  b"element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n3 0 1 5\n",
     "faces.ply: not a readable mesh; a face refers to vertex 5, the file has 2 vertices"),
])
def test_bad_mesh_files_give_clear_errors(tmp_path, name, content, message):
    (tmp_path / name).write_bytes(content)
    with pytest.raises(MeshError, match=message):
        load_mesh_file(tmp_path / name)


def test_missing_mesh_file(tmp_path):
    with pytest.raises(MeshError, match="not found"):
        load_mesh_file(tmp_path / "nope.obj")


def test_gltf_meshes_are_turned_to_z_up_and_front_x(tmp_path):
    # A glTF box: 0.4 tall along glTF's up (+y), 0.2 deep along its front (+z), 0.1 wide (x).
    trimesh.creation.box(extents=(0.1, 0.4, 0.2)).export(tmp_path / "tall.glb")
    trimesh.creation.box(extents=(0.1, 0.4, 0.2)).export(tmp_path / "tall.obj")
    gltf = load_mesh_file(tmp_path / "tall.glb", size=0.4)
    np.testing.assert_allclose(gltf.extents, [0.2, 0.1, 0.4], atol=1e-9)   # front x, width y, up z
    other = load_mesh_file(tmp_path / "tall.obj", size=0.4)
    np.testing.assert_allclose(other.extents, [0.1, 0.4, 0.2], atol=1e-9)  # other formats as they are


def test_y_up_files_are_turned_as_gltf_is_when_the_spec_says_so(tmp_path):
    from spm_data.errors import SpecError
    from spm_data.core.specs import parse_spec

    trimesh.creation.box(extents=(0.1, 0.4, 0.2)).export(tmp_path / "tall.ply")
    turned = load_mesh_file(tmp_path / "tall.ply", size=0.4, up="y")
    np.testing.assert_allclose(turned.extents, [0.2, 0.1, 0.4], atol=1e-9)   # as the glTF above
    base = 'class = "t"\n[mesh]\nsource = "files"\nfiles = ["tall.ply"]\n'
    plain, y_up = (parse_spec(base + extra, base_dir=str(tmp_path)) for extra in ("", 'up = "y"\n'))
    assert y_up.mesh.up == "y" and plain.fingerprint() != y_up.fingerprint()
    assert plain.fingerprint() == parse_spec(base + 'up = "z"\n', base_dir=str(tmp_path)).fingerprint()
    with pytest.raises(SpecError, match='mesh.up: expected "z" or "y"'):
        parse_spec(base + 'up = "x"\n', base_dir=str(tmp_path))
    with pytest.raises(SpecError, match="mesh.up: only for mesh files"):
        parse_spec('class = "cup"\n[mesh]\nup = "y"\n')


def test_uvs_without_an_image_get_the_procedural_texture(tmp_path):
    box = trimesh.creation.box(extents=(1, 1, 1))
    box.visual = trimesh.visual.TextureVisuals(uv=np.random.default_rng(0).random((len(box.vertices), 2)))
    box.export(tmp_path / "uv.ply")   # texture_u/v, no TextureFile: trimesh reads a 2x2 grey placeholder
    mesh = load_mesh_file(tmp_path / "uv.ply")
    assert mesh.texture.shape[0] > 2 and mesh.texture.std() > 20
    np.testing.assert_array_equal(mesh.texture, load_mesh_file(tmp_path / "uv.ply", texture="procedural").texture)


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

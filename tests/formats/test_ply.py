"""PLY: save_ply / load_ply round trips, and reading other writers' files."""

import numpy as np
import pytest
import trimesh

from spm_data.errors import SpmError
from spm_data.formats.ply import load_ply, save_ply


def test_round_trip_keeps_every_array(tmp_path):
    m = trimesh.creation.icosphere(subdivisions=2)
    rng = np.random.default_rng(0)
    colors = rng.integers(0, 256, (len(m.vertices), 3)).astype(np.uint8)
    uv = rng.random((len(m.vertices), 2))
    save_ply(tmp_path / "a.ply", m.vertices * 1000, m.faces, normals=m.vertex_normals, colors=colors, uv=uv,
             texture_file="a.png")
    back = load_ply(tmp_path / "a.ply")
    np.testing.assert_allclose(back["vertices"], m.vertices * 1000, rtol=1e-6)   # float32 on disk
    np.testing.assert_array_equal(back["faces"], m.faces)
    np.testing.assert_allclose(back["normals"], m.vertex_normals, atol=1e-6)
    np.testing.assert_array_equal(back["colors"], colors)
    np.testing.assert_allclose(back["uv"], uv, atol=1e-7)
    assert back["texture_file"] == "a.png"
    header = (tmp_path / "a.ply").read_bytes().split(b"end_header")[0].decode()
    assert "comment TextureFile a.png" in header and "property float texture_u" in header
    assert "property list uchar int vertex_indices" in header


def test_reads_trimesh_ascii_and_binary_files(tmp_path):
    m = trimesh.creation.box(extents=(1, 2, 3))
    for encoding in ("ascii", "binary"):
        m.export(tmp_path / f"{encoding}.ply", encoding=encoding)
        back = load_ply(tmp_path / f"{encoding}.ply")
        np.testing.assert_allclose(back["vertices"], m.vertices, rtol=1e-6)
        np.testing.assert_array_equal(back["faces"], m.faces)
        assert "uv" not in back and "texture_file" not in back


def test_bad_files_are_one_line_errors(tmp_path):
    (tmp_path / "x.ply").write_bytes(b"solid not a ply\n")
    with pytest.raises(SpmError, match="not a PLY file"):
        load_ply(tmp_path / "x.ply")
    save_ply(tmp_path / "t.ply", np.zeros((3, 3)), [[0, 1, 2]])
    data = (tmp_path / "t.ply").read_bytes()
    (tmp_path / "t.ply").write_bytes(data[:-5])   # truncated
    with pytest.raises(SpmError, match="unreadable PLY"):
        load_ply(tmp_path / "t.ply")
    with pytest.raises(SpmError, match="normals has shape"):
        save_ply(tmp_path / "n.ply", np.zeros((3, 3)), [[0, 1, 2]], normals=np.zeros((2, 3)))

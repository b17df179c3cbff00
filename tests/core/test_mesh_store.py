"""The content-named mesh store: digests ignore names, entries prove what they are, carrying verifies."""

import numpy as np
import pytest

from spm_data.errors import MeshError
from spm_data.core.mesh_store import (carry_meshes, has_mesh, load_mesh, mesh_digest, save_mesh, store_path)
from spm_data.core.meshes import TexturedMesh
from spm_data.core.shapes import procedural_mesh
from spm_data.core.symmetries import Symmetries


def _renamed(mesh, name):
    return TexturedMesh(name, mesh.vertices, mesh.faces, mesh.normals, mesh.uv, mesh.texture, mesh.symmetries)


def test_round_trip_is_exact_and_the_digest_is_the_content_not_the_name(tmp_path):
    cup = procedural_mesh("cup", 0, seed=3, size=0.25)
    digest = save_mesh(tmp_path, cup)
    back = load_mesh(tmp_path, digest)
    assert back.name == cup.name and mesh_digest(back) == digest
    for key in ("vertices", "faces", "normals", "uv", "texture"):
        assert np.array_equal(getattr(back, key), getattr(cup, key))
    assert len(back.symmetries.continuous) == len(cup.symmetries.continuous)
    assert mesh_digest(_renamed(cup, "another name")) == digest
    assert mesh_digest(procedural_mesh("cup", 1, seed=3, size=0.25)) != digest
    assert mesh_digest(procedural_mesh("cup", 0, seed=3, size=0.26)) != digest
    turned = TexturedMesh(cup.name, cup.vertices, cup.faces, cup.normals, cup.uv, cup.texture,
                          Symmetries(continuous=(np.array([0.0, 0.0, 1.0]),)))
    assert (mesh_digest(turned) == digest) == (len(cup.symmetries.continuous) == 1 and not cup.symmetries.discrete)


def test_a_damaged_or_renamed_entry_is_refused_in_one_line(tmp_path):
    box = procedural_mesh("box", 0, seed=1, size=0.2)
    digest = save_mesh(tmp_path, box)
    path = store_path(tmp_path, digest)
    other = "0" * 64
    path.rename(store_path(tmp_path, other))
    with pytest.raises(MeshError, match="not the mesh its name says"):
        load_mesh(tmp_path, other)
    store_path(tmp_path, other).write_bytes(b"PK\x03\x04 not a zip")
    with pytest.raises(MeshError, match="not a mesh store entry"):
        load_mesh(tmp_path, other)
    with pytest.raises(MeshError, match="missing from the folder's mesh store"):
        load_mesh(tmp_path, digest)
    with pytest.raises(MeshError, match="not a mesh digest"):
        load_mesh(tmp_path, "../escape")


def test_carry_copies_what_is_named_and_refuses_what_no_source_has(tmp_path):
    a, b = procedural_mesh("ball", 0, seed=2, size=0.2), procedural_mesh("car", 0, seed=2, size=0.2)
    da, db = save_mesh(tmp_path / "one", a), save_mesh(tmp_path / "two", b)
    assert carry_meshes([da, db, "", da], [tmp_path / "one", tmp_path / "two"], tmp_path / "out") == 2
    assert has_mesh(tmp_path / "out", da) and has_mesh(tmp_path / "out", db)
    assert carry_meshes([da], [tmp_path / "one"], tmp_path / "out") == 0
    with pytest.raises(MeshError, match="in no source's meshes/"):
        carry_meshes(["f" * 64], [tmp_path / "one"], tmp_path / "out")
    assert sorted(p.name for p in (tmp_path / "out" / "meshes").iterdir()) == sorted([f"{da}.npz", f"{db}.npz"])

"""Instances: which mesh each is, and rebuilding exactly the mesh a shard was rendered from."""

import json

import pytest
import trimesh

from spm_data.errors import MeshError
from spm_data.core.instances import instance_count, mesh_attrs, mesh_record, shard_mesh
from spm_data.io.files import file_sha256
from spm_data.core.specs import load_spec


def files_spec(folder):
    (folder / "meshes").mkdir(parents=True)
    for name, extents in (("a.obj", (1, 2, 3)), ("b.obj", (3, 2, 1))):
        trimesh.creation.box(extents=extents).export(folder / "meshes" / name)
    (folder / "s.toml").write_text('class = "u"\n[mesh]\nsource = "files"\nfiles = ["meshes/*.obj"]\n'
                                   'symmetries = ["x/180"]\n')
    return load_spec(folder / "s.toml")


def test_mesh_records_are_relative_to_the_spec_and_hashed(tmp_path):
    spec = files_spec(tmp_path / "p")
    assert instance_count(spec) == 2
    record = mesh_record(spec, 1)
    assert record == {"path": "meshes/b.obj", "sha256": file_sha256(tmp_path / "p" / "meshes" / "b.obj")}
    attrs = mesh_attrs(spec, {1: record})
    assert attrs["spec_dir"] == str((tmp_path / "p").resolve())
    assert json.loads(attrs["mesh_files"]) == {"1": record}


def test_procedural_specs_record_nothing_machine_specific(tmp_path):
    from spm_data.core.specs import parse_spec

    spec = parse_spec('class = "cup"')
    assert mesh_record(spec, 0) is None and mesh_attrs(spec, {0: None}) == {}


def test_shard_mesh_rebuilds_the_recorded_file_with_its_symmetries(tmp_path):
    spec = files_spec(tmp_path / "p")
    attrs = {"source": "synthetic", "spec": spec.text, "seed": 0, **mesh_attrs(spec, {1: mesh_record(spec, 1)})}
    mesh = shard_mesh(attrs, 1)
    assert mesh.name == "b" and mesh.extents[0] == pytest.approx(0.25)   # b is longest along x
    assert len(mesh.symmetries.discrete) == 1
    with pytest.raises(MeshError, match="does not record which file instance 0"):
        shard_mesh(attrs, 0)
    with pytest.raises(MeshError, match="made by an older spm"):
        shard_mesh({"source": "synthetic", "spec": spec.text, "seed": 0}, 1)
    assert shard_mesh({"source": "coil100"}, 0) is None

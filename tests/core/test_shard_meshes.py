"""Each frame's mesh by digest: stored meshes and meshes rebuilt for shards older than the store agree."""

import json

import numpy as np

from spm_data.pipelines.render_jobs import load_run_specs, render_dataset
from spm_data.core.mesh_store import has_mesh, load_mesh, mesh_digest
from spm_data.core.shard_meshes import FrameMeshes
from spm_data.io.folders import open_folder
from spm_data.io.shards import read_attrs, read_shard

CLUTTERED = """class = "cluttered"
seed = 4
[mesh]
generator = "cup"
instances = 2
[camera]
azimuth = [0, 15, 5]
distances = [0.7]
[image]
width = 48
height = 48
[distractors]
count = 2
visible = [0.4, 0.8]
classes = ["box", "ball"]
instances = 2
[render]
renderer = "pyrender"
"""


def test_stored_and_rebuilt_meshes_agree_for_targets_and_distractors(tmp_path):
    (tmp_path / "s").mkdir()
    (tmp_path / "s" / "cluttered.toml").write_text(CLUTTERED)
    render_dataset(load_run_specs(all_classes=True, specs_dir=tmp_path / "s"), tmp_path / "r")
    shard = open_folder(tmp_path / "r").shards[0]
    attrs = read_attrs(shard)
    data = read_shard(shard, ["instance_id", "instance_name", "mesh", "distractor_mesh"])
    stored = FrameMeshes(tmp_path / "r").targets(attrs, data)
    assert len(set(stored)) == 2 and all(has_mesh(tmp_path / "r", d) for d in stored)
    older = FrameMeshes(tmp_path / "r")   # as for a shard written before the store: rebuilt from the spec
    rebuilt = older.targets(attrs, {"instance_id": data["instance_id"]})
    assert rebuilt == stored and set(older.rebuilt) == set(stored)
    for digest in set(stored):
        assert load_mesh(tmp_path / "r", digest).name == older.mesh(digest).name
    pool = FrameMeshes(tmp_path / "r").pool(attrs)
    used = {int(k) for k in np.ravel(data["distractor_mesh"]) if k >= 0}
    assert {k for k, d in enumerate(pool) if d} == used and all(has_mesh(tmp_path / "r", pool[k]) for k in used)
    old_attrs = {k: v for k, v in attrs.items() if k != "distractor_mesh_digests"}
    rebuilt_pool = FrameMeshes(tmp_path / "r").pool(old_attrs)
    assert len(rebuilt_pool) == len(json.loads(attrs["distractor_meshes"]))
    assert all(rebuilt_pool[k] == pool[k] for k in used)
    assert FrameMeshes(tmp_path / "r").mesh("") is None
    assert mesh_digest(FrameMeshes(tmp_path / "r").mesh(stored[0])) == stored[0]

"""spm_data.pipelines.merge: folders merged into full shards per image size, every frame once,
sources filtered, classes renamed; mixed schemas refused (the coil_folder fixture: tests/conftest.py)."""

import numpy as np
from click.testing import CliRunner

from cli import data_cli
from spm_data.pipelines.merge import merge_folders
from spm_data.pipelines.render_jobs import load_run_specs, render_dataset
from spm_data.formats.coil100 import import_coil100
from spm_data.io.shards import list_shards, read_manifest, read_shard


def test_merge_keeps_every_frame_once(small_specs_dir, coil_folder, tmp_path):
    render_dataset(load_run_specs(all_classes=True, specs_dir=small_specs_dir), tmp_path / "syn", limit=12)
    import_coil100(coil_folder, tmp_path / "coil")
    merge_folders([tmp_path / "syn", tmp_path / "coil"], tmp_path / "m", frames_per_shard=50,
                  renames={"coil100-obj7": "cup"})
    manifest = read_manifest(tmp_path / "m")
    assert manifest["frames"] == 24 + 142
    assert [s["folder"] for s in manifest["sources"]] == [str(tmp_path / "syn"), str(tmp_path / "coil")]
    assert manifest["classes"]["cup"] == 12 + 72 and "coil100-obj7" not in manifest["classes"]
    sizes = {e["file"]: e["frames"] for e in manifest["shards"]}
    assert sizes == {"merged-128x128-00000.h5": 50, "merged-128x128-00001.h5": 50, "merged-128x128-00002.h5": 42,
                     "merged-64x64-00000.h5": 24}  # full shards per image size, the last of each partial

    def identities(folders):
        rows = []
        for folder in folders:
            for p in list_shards(folder):
                d = read_shard(p, ["instance_name", "pose", "rgb"])
                rows += [(n, tuple(np.round(y, 9)), hash(img.tobytes()))
                         for n, y, img in zip(d["instance_name"], d["pose"], d["rgb"])]
        return sorted(rows)

    merged, inputs = identities([tmp_path / "m"]), identities([tmp_path / "syn", tmp_path / "coil"])
    assert merged == inputs and len(set(merged)) == len(merged)  # every frame exactly once


def test_merge_filters_sources_and_refuses_mixed_schemas(small_specs_dir, coil_folder, tmp_path):
    render_dataset(load_run_specs(["cup"], specs_dir=small_specs_dir), tmp_path / "syn", limit=6)
    import_coil100(coil_folder, tmp_path / "coil")
    merge_folders([tmp_path / "syn", tmp_path / "coil"], tmp_path / "only", sources=["synthetic"])
    assert read_manifest(tmp_path / "only")["frames"] == 6
    import h5py

    with h5py.File(list_shards(tmp_path / "syn")[0], "a") as f:
        f.attrs["schema_version"] = 0
    r = CliRunner().invoke(data_cli, ["merge", str(tmp_path / "syn"), str(tmp_path / "coil"), "--out",
                                      str(tmp_path / "bad")])
    assert r.exit_code == 1 and "schema version 0 is older than this spm (3) and cannot be verified" in r.output
    assert not (tmp_path / "bad").exists()

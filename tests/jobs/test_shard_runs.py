"""Resume verifies what it finds; a run that makes nothing leaves nothing; a folder in the manifest's place."""

import numpy as np
import pytest
from click.testing import CliRunner

from cli import data_cli
from spm_data.errors import ShardError, SpmWarning
from tests.helpers import flip_stored_byte
from spm_data.pipelines.render_jobs import load_run_specs, render_dataset
from spm_data.io.shards import list_shards, read_manifest, read_shard, verify_shard

SPEC = ('class = "cup"\nseed = 2\n[mesh]\ninstances = 1\n[camera]\nazimuth = [0, 55, 5]\n'
        'elevation = [20, 20, 5]\ndistances = [0.6]\n[image]\nwidth = 64\nheight = 64\n'
        '[render]\nrenderer = "pyrender"\nframes_per_shard = 4\n')


def specs(tmp_path, text=SPEC):
    folder = tmp_path / "specs"
    folder.mkdir(exist_ok=True)
    (folder / "cup.toml").write_text(text)
    return load_run_specs(["cup"], specs_dir=folder)


def test_resume_redoes_corrupt_and_truncated_shards_naming_them(tmp_path):
    out = tmp_path / "out"
    render_dataset(specs(tmp_path), out)
    before = {p.name: read_shard(p, ["mask", "pose"]) for p in list_shards(out)}
    corrupt, truncated = out / "cup-00001.h5", out / "cup-00002.h5"
    flip_stored_byte(corrupt, "rgb")
    truncated.write_bytes(truncated.read_bytes()[:3000])
    summary = render_dataset(specs(tmp_path), out)
    assert sorted(summary.done) == ["cup-00001.h5", "cup-00002.h5"] and len(summary.skipped) == 1
    redone = dict(summary.redone)
    assert set(redone) == {"cup-00001.h5", "cup-00002.h5"}
    assert "field 'rgb' fails its checksum" in redone["cup-00001.h5"]
    assert "not a readable HDF5 shard" in redone["cup-00002.h5"]
    assert "redone cup-00002.h5: " in summary.report()
    for path in list_shards(out):
        verify_shard(path)
        again = read_shard(path, ["mask", "pose"])
        assert np.array_equal(again["mask"], before[path.name]["mask"])
        assert np.array_equal(again["pose"], before[path.name]["pose"])
    assert read_manifest(out)["frames"] == 12


def test_a_run_that_makes_no_shard_leaves_no_manifest_and_no_folder(tmp_path):
    (tmp_path / "specs").mkdir()
    (tmp_path / "specs" / "broken.obj").write_text("v 0 0 0\nv 1 0 0\nthis is not a mesh\n")
    spec = SPEC.replace("[mesh]\ninstances = 1", '[mesh]\nsource = "files"\nfiles = ["broken.obj"]')
    (tmp_path / "specs" / "cup.toml").write_text(spec)
    out = tmp_path / "out"
    r = CliRunner().invoke(data_cli, ["render", "--spec", str(tmp_path / "specs" / "cup.toml"), "--out", str(out)])
    assert r.exit_code == 1 and "Traceback" not in r.output
    # Every shard failed alike and none was made: that one error, not a summary of an empty folder.
    assert r.output.startswith("error: ") and r.output.count("\n") == 1 and "broken.obj" in r.output
    assert not out.exists()


def test_a_folder_where_the_manifest_goes_is_one_line(tmp_path):
    out = tmp_path / "out"
    (out / "manifest.json").mkdir(parents=True)
    r = CliRunner().invoke(data_cli, ["render", "--spec", str(tmp_path / "none.toml"), "--out", str(out)])
    (tmp_path / "specs").mkdir()
    (tmp_path / "specs" / "cup.toml").write_text(SPEC)
    r = CliRunner().invoke(data_cli, ["render", "--spec", str(tmp_path / "specs" / "cup.toml"), "--out", str(out)])
    assert r.exit_code == 1 and r.output.startswith("error: ") and r.output.count("\n") == 1
    assert "manifest.json is a folder, not a manifest; move it away" in r.output
    assert list_shards(out) == []


def test_a_run_with_failed_shards_names_them_and_readers_refuse_the_folder(tmp_path):
    import trimesh

    from spm_data.io.folders import open_folder

    folder = tmp_path / "specs"
    folder.mkdir()
    trimesh.creation.box(extents=(1, 2, 3)).export(folder / "a-good.obj")
    (folder / "b-broken.obj").write_text("v 0 0 0\nv 1 0 0\nthis is not a mesh\n")
    spec = SPEC.replace("[mesh]\ninstances = 1", '[mesh]\nsource = "files"\nfiles = ["*.obj"]')
    spec = spec.replace("frames_per_shard = 4", "frames_per_shard = 12")   # one shard per mesh
    (folder / "cup.toml").write_text(spec)
    out = tmp_path / "out"
    r = CliRunner().invoke(data_cli, ["render", "--spec", str(folder / "cup.toml"), "--out", str(out)])
    assert r.exit_code == 1 and "failed cup-00001.h5" in r.output
    assert read_manifest(out)["missing"] == ["cup-00001.h5"] and read_manifest(out)["frames"] == 12
    with pytest.raises(ShardError, match=r"did not finish: 1 planned shard\(s\) are missing \(cup-00001.h5\)"):
        open_folder(out)
    with pytest.warns(SpmWarning, match="reading the complete ones"):
        assert [p.name for p in open_folder(out, allow_partial=True).shards] == ["cup-00000.h5"]
    r = CliRunner().invoke(data_cli, ["export", "bop", str(out), "--out", str(tmp_path / "bop")])
    assert r.exit_code == 1 and "did not finish" in r.output and not (tmp_path / "bop").exists()
    r = CliRunner().invoke(data_cli, ["validate", str(out)])
    assert r.exit_code == 1 and "did not make cup-00001.h5" in r.output
    # Fixed and run again: the manifest no longer names anything missing.
    trimesh.creation.box(extents=(3, 2, 1)).export(folder / "b-broken.obj")
    r = CliRunner().invoke(data_cli, ["render", "--spec", str(folder / "cup.toml"), "--out", str(out)])
    assert r.exit_code == 0 and read_manifest(out)["missing"] == [] and len(open_folder(out).shards) == 2

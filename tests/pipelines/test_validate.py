import json
import shutil

import h5py
import numpy as np
import pytest
from click.testing import CliRunner

from cli import data_cli
from spm_data.pipelines.render_jobs import load_run_specs, render_dataset
from spm_data.io.shards import SCHEMA_VERSION, read_attrs, read_shard, write_manifest, write_shard
from spm_data.pipelines.validate import validate_folder


@pytest.fixture(scope="module")
def good(tmp_path_factory, small_specs_dir_module):
    out = tmp_path_factory.mktemp("good")
    render_dataset(load_run_specs(["cup"], specs_dir=small_specs_dir_module), out, limit=16)
    return out


@pytest.fixture(scope="module")
def small_specs_dir_module(tmp_path_factory):
    from tests.helpers import SMALL_SPEC

    folder = tmp_path_factory.mktemp("specs")
    (folder / "cup.toml").write_text(SMALL_SPEC.format(cls="cup", seed=3))
    return folder


def copy(good, tmp_path):
    shutil.copytree(good, tmp_path / "d")
    return tmp_path / "d"


def messages(folder):
    return [f"{where}: {msg}" for where, msg in validate_folder(folder)]


def test_a_good_folder_is_valid(good):
    assert validate_folder(good) == []
    r = CliRunner().invoke(data_cli, ["validate", str(good)])
    assert r.exit_code == 0 and "all shards valid" in r.output


def test_flipped_byte_is_caught(good, tmp_path):
    d = copy(good, tmp_path)
    shard = d / "cup-00000.h5"
    raw = bytearray(shard.read_bytes())
    raw[len(raw) // 2] ^= 0xFF
    shard.write_bytes(bytes(raw))
    found = messages(d)
    assert any("cup-00000.h5: checksum differs from the manifest" in m or "corrupt" in m for m in found), found
    r = CliRunner().invoke(data_cli, ["validate", str(d)])
    assert r.exit_code == 1 and "cup-00000.h5" in r.output


def test_truncated_shard_is_caught(good, tmp_path):
    d = copy(good, tmp_path)
    shard = d / "cup-00001.h5"
    shard.write_bytes(shard.read_bytes()[:5000])
    found = messages(d)
    assert any("cup-00001.h5: not a readable HDF5 shard" in m for m in found), found
    assert any("cup-00001.h5: size 5000 bytes, manifest says" in m for m in found), found


def test_newer_schema_is_caught(good, tmp_path):
    d = copy(good, tmp_path)
    with h5py.File(d / "cup-00000.h5", "a") as f:
        f.attrs["schema_version"] = SCHEMA_VERSION + 1
    assert any(f"schema version {SCHEMA_VERSION + 1} is newer than this spm" in m for m in messages(d))


def test_manifest_disagreeing_with_files_is_caught(good, tmp_path):
    d = copy(good, tmp_path)
    m = json.loads((d / "manifest.json").read_text())
    m["shards"][0]["frames"] += 1
    m["shards"].append(dict(m["shards"][1], file="cup-00099.h5", sha256="0" * 64))   # not a copy: only missing
    (d / "manifest.json").write_text(json.dumps(m))
    found = messages(d)
    assert "manifest.json: lists cup-00099.h5, which is not in the folder" in found
    assert "cup-00000.h5: manifest says 9 frames, the shard has 8" in found
    assert any("is not the sum of its shards" in f for f in found)
    (d / "manifest.json").unlink()
    assert messages(d) == ["manifest.json: no manifest.json"]


def test_bad_values_inside_a_shard_are_caught(good, tmp_path):
    d = copy(good, tmp_path)
    arrays = read_shard(d / "cup-00000.h5")   # written again with bad values: intact, but wrong
    arrays["R"][2] *= 2.0
    arrays["t"][3, 0] = np.nan
    arrays["mask"][5] = 0
    write_shard(d / "cup-00000.h5", arrays, read_attrs(d / "cup-00000.h5"))
    write_manifest(d)
    found = " | ".join(messages(d))
    assert "R is not a rotation in frames [2]" in found
    assert "non-finite t in frames [3]" in found
    assert "empty mask in 1 frames (first: [5])" in found


def test_folder_without_shards(tmp_path):
    r = CliRunner().invoke(data_cli, ["validate", str(tmp_path)])
    assert r.exit_code == 1 and "no shards (*.h5) in" in r.output and "nothing to validate" in r.output


def test_a_missing_or_damaged_mesh_store_entry_is_a_problem(good, tmp_path):
    folder = tmp_path / "copy"
    shutil.copytree(good, folder)
    assert validate_folder(folder) == []
    entries = sorted((folder / "meshes").iterdir())
    assert len(entries) == 2   # the cup's 2 instances
    data = bytearray(entries[0].read_bytes())
    data[len(data) // 2] ^= 0x10
    entries[0].write_bytes(bytes(data))
    entries[1].unlink()
    problems = validate_folder(folder)
    assert sorted(where for where, _ in problems) == sorted(f"meshes/{e.name[:12]}…" for e in entries[:2])
    said = " ".join(msg for _, msg in problems)
    assert "missing from the folder's mesh store" in said and ("damaged" in said)


def test_a_damaged_manifest_is_named_once(good, tmp_path):
    d = copy(good, tmp_path)
    (d / "manifest.json").write_text(json.dumps({"shards": [None]}))
    found = [f for f in messages(d) if f.startswith("manifest.json")]
    assert len(found) == 1 and found[0].startswith("manifest.json: shards[0] is null, not an entry"), found
    r = CliRunner().invoke(data_cli, ["validate", str(d)])
    assert r.exit_code == 1 and "manifest.json: manifest.json" not in r.output, r.output


def test_a_folder_whose_writer_was_killed_names_its_leftovers(good, tmp_path):
    import os

    d = copy(good, tmp_path)
    (d / "manifest.json").unlink()
    (d / ".cup-00002.h5.partial").write_bytes(b"half a shard")
    (d / ".spm.lock").write_text("not a lock record")
    os.utime(d / ".spm.lock", (0, 0))   # unreadable and old: its run is gone
    assert messages(d) == ["manifest.json: no manifest.json: the run that wrote this folder was stopped before it "
                           "finished (killed?) and left .cup-00002.h5.partial, .spm.lock (its run is gone); run that "
                           "command again to finish it (it resumes, and removes them)"]
    write_manifest(d)   # a finished run, beside a partial file of a later one that was killed
    (d / ".spm.lock").unlink()
    assert messages(d) == [".cup-00002.h5.partial: left by a run that was stopped before it finished (killed?); the "
                           "next run into this folder removes it"]

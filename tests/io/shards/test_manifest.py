"""spm_data.io.shards.manifest: a folder's shards, their frame counts and checksums in manifest.json."""

import json

import pytest

from spm_data.errors import ShardError
from spm_data.io.files import file_sha256
from spm_data.io.shards import read_manifest, write_manifest, write_shard
from tests.helpers import make_arrays


def test_manifest_lists_shards_with_counts_and_checksums(tmp_path):
    a = make_arrays(n=3)
    a["class_name"] = ["cup", "cup", "box"]
    write_shard(tmp_path / "s0.h5", a, {"seed": 0, "renderer": "x"})
    write_shard(tmp_path / "s1.h5", make_arrays(n=2), {"seed": 0, "renderer": "x"})
    (tmp_path / ".s2.h5.partial").write_bytes(b"half")
    payload = write_manifest(tmp_path)
    on_disk = read_manifest(tmp_path)
    assert payload == on_disk
    assert [e["file"] for e in on_disk["shards"]] == ["s0.h5", "s1.h5"]
    assert on_disk["frames"] == 5
    assert on_disk["classes"] == {"box": 1, "class_name-0": 1, "class_name-1": 1, "cup": 2}
    assert on_disk["shards"][0]["sha256"] == file_sha256(tmp_path / "s0.h5")
    json.loads((tmp_path / "manifest.json").read_text())


@pytest.mark.parametrize("change, message", [
    ({"missing": 7}, "'missing' is 7, not a list of shard names"),
    ({"missing": "abc"}, "'missing' is \"abc\", not a list of shard names"),
    ({"shards": [None]}, "shards[0] is null, not an entry with a 'file' name"),
    ({"shards": [{"file": "s0.h5", "frames": "3"}]}, "shards[0] (s0.h5): 'frames' is \"3\", not a count"),
    ({"frames": -1}, "'frames' is -1, not a count"),
])
def test_a_manifest_with_values_of_the_wrong_type_is_one_error(tmp_path, change, message):
    write_shard(tmp_path / "s0.h5", make_arrays(n=3), {"seed": 0, "renderer": "x"})
    payload = {**write_manifest(tmp_path), **change}
    (tmp_path / "manifest.json").write_text(json.dumps(payload))
    with pytest.raises(ShardError) as info:
        read_manifest(tmp_path)
    assert str(info.value) == (f"{tmp_path}/manifest.json: {message}; the manifest is damaged: run the command "
                               "that wrote the folder again, or delete it and pass --allow-partial")

"""spm_data.io.folders: a shard folder read by its manifest: listed shards only, a live run's
folder refused, gaps errors (or warnings with allow_partial), shard trees found recursively."""

import os
import re
import warnings

import pytest

from spm_data.errors import ShardError, SpmWarning
from spm_data.io.folders import ShardFolder, find_folders, open_folder, open_tree
from spm_data.io.locking import OutputLock
from spm_data.io.shards import write_manifest, write_shard
from tests.helpers import make_arrays


def shard_folder(folder, names=("a-00000.h5", "a-00001.h5"), manifest=True, first_seed=0):
    """Shards of 2 frames each, shard k of seed first_seed + k (a seed's frames are the same frames)."""
    folder.mkdir(parents=True)
    for k, name in enumerate(names, start=first_seed):
        write_shard(folder / name, make_arrays(n=2, seed=k), {"renderer": "test", "seed": k})
    if manifest:
        write_manifest(folder)
    return folder


def opened(folder, **kwargs):
    """open_folder's result and the SpmWarning messages it gave."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = open_folder(folder, **kwargs)
    return result, [str(w.message) for w in caught if issubclass(w.category, SpmWarning)]


def test_a_finished_folder_is_its_manifests_shards(tmp_path):
    folder = shard_folder(tmp_path / "s")
    result, warned = opened(folder)
    assert result.path == folder and result.shards == (folder / "a-00000.h5", folder / "a-00001.h5")
    assert result.ignored == () and result.manifest["frames"] == 4 and warned == []
    single = open_folder(folder / "a-00001.h5")
    assert single == ShardFolder(folder, (folder / "a-00001.h5",))


def test_missing_and_empty_folders(tmp_path):
    with pytest.raises(ShardError, match=f"^no such folder or shard: {re.escape(str(tmp_path / 'none'))}$"):
        open_folder(tmp_path / "none")
    (tmp_path / "empty").mkdir()
    with pytest.raises(ShardError, match=r"no shards \(\*\.h5\) in"):
        open_folder(tmp_path / "empty")


def test_no_manifest_is_an_error_unless_allow_partial(tmp_path):
    folder = shard_folder(tmp_path / "s", manifest=False)
    with pytest.raises(ShardError) as info:
        open_folder(folder)
    assert str(info.value) == (f"{folder}: no manifest.json, so no finished run made these 2 shards (a run writes it "
                               "last, also when interrupted); run that command again to finish it, or pass "
                               "--allow-partial")
    result, warned = opened(folder, allow_partial=True)
    assert len(result.shards) == 2 and result.manifest is None
    assert warned == [f"{folder}: no manifest.json; reading the 2 complete shards on disk (--allow-partial)"]


def test_a_changed_shard_is_a_gap_and_a_stray_one_is_ignored(tmp_path):
    folder = shard_folder(tmp_path / "s")
    listed = (folder / "a-00001.h5").stat().st_size
    with open(folder / "a-00001.h5", "ab") as fh:
        fh.write(b"more")
    write_shard(folder / "stray.h5", make_arrays(n=1), {"renderer": "test", "seed": 9})
    with pytest.raises(ShardError, match=rf"a-00001.h5: {listed + 4} bytes on disk, manifest.json says {listed}; "
                                         r"it changed after the run wrote it; run `spm-data validate` on it"):
        open_folder(folder)
    result, warned = opened(folder, allow_partial=True)
    assert result.shards == (folder / "a-00000.h5",) and result.ignored == (folder / "stray.h5",)
    assert warned[0].endswith("it changed after the run wrote it; skipped (--allow-partial)")
    assert warned[1] == f"{folder}: ignoring 1 shard(s) manifest.json does not list (stray.h5)"


def test_a_folder_a_live_run_holds_is_refused_naming_it(tmp_path):
    folder = shard_folder(tmp_path / "s")
    with OutputLock(folder):
        with pytest.raises(ShardError, match=rf"^{re.escape(str(folder))}/ is still being written by pid "
                                             rf"{os.getpid()} on host .*; wait for that run to finish, or pass "
                                             "--allow-partial"):
            open_folder(folder)
        result, warned = opened(folder, allow_partial=True)
    assert len(result.shards) == 2 and len(warned) == 1
    assert warned[0].startswith(f"{folder}/ is still being written by pid {os.getpid()}")
    assert warned[0].endswith("; reading the shards complete so far (--allow-partial)")


def test_a_tree_of_folders_hidden_ones_skipped(tmp_path):
    root = tmp_path / "root"
    shard_folder(root / "render", names=("r-00000.h5",), first_seed=5)
    shard_folder(root / "deep" / "occluded", names=("o-00000.h5", "o-00001.h5"))
    shard_folder(root / ".spm-features", names=("cache.h5",))
    (root / "notes").mkdir()
    assert find_folders(root) == [root / "deep" / "occluded", root / "render"]
    assert find_folders(root / "render" / "r-00000.h5") == [root / "render" / "r-00000.h5"]
    assert [p.name for p in open_tree(root)] == ["o-00000.h5", "o-00001.h5", "r-00000.h5"]
    with pytest.raises(ShardError, match="no such folder"):
        find_folders(tmp_path / "none")
    with pytest.raises(ShardError, match="no shards"):
        open_tree(root / "notes")


def test_a_copy_is_refused_whatever_the_manifest_says_and_across_a_tree(tmp_path):
    import json
    import shutil

    folder = shard_folder(tmp_path / "f")
    shutil.copy(folder / "a-00000.h5", folder / "copy.h5")
    payload = json.loads((folder / "manifest.json").read_text())
    payload["shards"].append({"file": "copy.h5", "frames": 2})   # no sha256: the bytes decide
    (folder / "manifest.json").write_text(json.dumps(payload))
    for partial in (False, True):
        with pytest.raises(ShardError, match=re.escape("a-00000.h5 and copy.h5 have the same content (SHA-256 ")):
            open_folder(folder, allow_partial=partial)
    shard_folder(tmp_path / "tree" / "one")
    shard_folder(tmp_path / "tree" / "two", names=("b-00000.h5",), first_seed=1)   # a-00001's frames again
    with pytest.raises(ShardError, match="have the same content"):
        open_tree(tmp_path / "tree")

"""spm_data.io.shards.identity: duplicates decided from what the shards hold: a byte copy under
any name, a frame written again into another shard (a merge), never an occluded frame."""

import shutil

import numpy as np
import pytest

from spm_data.io.shards import read_shard, write_shard
from spm_data.io.shards.identity import frame_keys, read_twice
from tests.helpers import flip_stored_byte, make_arrays


def shard(path, seed=0, n=3, **change):
    arrays = {**make_arrays(n=n, h=8, w=10, seed=seed), **change}
    return write_shard(path, arrays, {"renderer": "test", "seed": seed})


def test_distinct_shards_pass_and_each_frame_has_its_own_key(tmp_path):
    a, b = shard(tmp_path / "a.h5", seed=0), shard(tmp_path / "b.h5", seed=1)
    assert read_twice([a, b]) is None
    keys = frame_keys(a) + frame_keys(b)
    assert len(set(keys)) == 6 and all(len(k) == 32 for k in keys)


def test_a_byte_copy_under_another_name_is_found_by_its_content(tmp_path):
    a = shard(tmp_path / "a.h5")
    shutil.copy(a, tmp_path / "copy.h5")
    said = read_twice([a, tmp_path / "copy.h5"], name=lambda p: p.name)
    assert said.startswith("a.h5 and copy.h5 have the same content (SHA-256 ") and "read twice" in said


def test_a_frame_written_again_in_another_shard_is_found(tmp_path):
    a = shard(tmp_path / "a.h5", seed=0)
    frames = read_shard(a, frames=np.array([2]))
    other = make_arrays(n=2, h=8, w=10, seed=7)
    merged = {k: np.concatenate([other[k], frames[k]]) for k in other}   # a merge: frame 2 of a is frame 2 here too
    m = write_shard(tmp_path / "m.h5", merged, {"renderer": "merged", "seed": 0})
    assert read_twice([a, m], name=lambda p: p.name) == ("frame 2 of m.h5 is frame 2 of a.h5 (the same image, camera "
                                                         "and names), so it would be read twice")


@pytest.mark.parametrize("change", ["rgb", "R"])
def test_other_pixels_or_another_camera_is_another_frame(tmp_path, change):
    a = shard(tmp_path / "a.h5", seed=0)
    d = read_shard(a)
    if change == "rgb":   # an occluded copy: a rectangle blacked out
        d["rgb"][:, 2:5, 2:5] = 0
    else:
        d["R"] = d["R"][:, :, [1, 0, 2]] * [1, 1, -1]
    b = write_shard(tmp_path / "b.h5", d, {"renderer": "merged", "seed": 0})
    assert read_twice([a, b]) is None


def test_a_shard_that_cannot_be_read_is_left_to_its_reader(tmp_path):
    a, b = shard(tmp_path / "a.h5", seed=0), shard(tmp_path / "b.h5", seed=1)
    flip_stored_byte(b, "rgb")
    assert read_twice([a, b]) is None   # the read that follows names the corrupt shard


def test_only_merged_shards_are_compared_frame_by_frame(tmp_path):
    """An occluded copy whose rectangle covered nothing (or two such copies) has its source's
    pixels and labels: its own copy, not a merge's repeat, so not refused."""
    a = shard(tmp_path / "a.h5", seed=0)
    copy = write_shard(tmp_path / "copy.h5", {**read_shard(a), "occlusion_fraction": np.zeros(3, np.float32)},
                       {"renderer": "test", "seed": 1})   # other attributes: other bytes, the same frames
    assert read_twice([a, copy]) is None
    merged = write_shard(tmp_path / "m.h5", read_shard(a), {"renderer": "merged", "seed": 0})
    assert read_twice([a, copy, merged], name=lambda p: p.name).startswith("frame 0 of m.h5 is frame 0 of a.h5")
    # merged, the two land in two shards of one merge: still two copies of the merge's own inputs
    (tmp_path / "m").mkdir()
    one = write_shard(tmp_path / "m" / "m0.h5", read_shard(a), {"renderer": "merged", "seed": 0})
    two = write_shard(tmp_path / "m" / "m1.h5", read_shard(copy), {"renderer": "merged", "seed": 1})
    assert read_twice([one, two]) is None

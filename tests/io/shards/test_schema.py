"""spm_data.io.shards.schema: arrays are checked against the schema before anything is written."""

import numpy as np
import pytest

from spm_data.errors import ShardError
from spm_data.io.shards import write_shard
from tests.helpers import make_arrays


@pytest.mark.parametrize("mutate, message", [
    (lambda a: a.pop("mask"), "missing mask"),
    (lambda a: a.update(depth=a["depth"].astype(np.float64)), "expected dtype float32"),
    (lambda a: a.update(R=a["R"][:, :2]), "'R': expected shape"),
    (lambda a: a.update(extra=np.zeros(3)), "unknown fields extra"),
])
def test_bad_arrays_are_refused_and_nothing_is_written(tmp_path, mutate, message):
    arrays = make_arrays()
    mutate(arrays)
    with pytest.raises(ShardError, match=message):
        write_shard(tmp_path / "a.h5", arrays, {})
    assert list(tmp_path.iterdir()) == []


def test_expected_shape_fills_in_the_shard_sizes():
    from spm_data.io.shards.schema import check_arrays, expected_shape

    assert expected_shape("rgb", 3, 8, 10) == (3, 8, 10, 3)
    assert expected_shape("occlusion_rects", 3, 8, 10, {"R": 2}) == (3, 2, 4)
    assert expected_shape("occlusion_rects", 3, 8, 10) == (3, 1, 4)     # one rectangle unless told
    assert expected_shape("visible_mask", 2, 5, 6) == (2, 5, 6)     # an optional field
    assert expected_shape("normals", 2, 5, 6) == (2, 5, 6, 3)
    assert expected_shape("distractor_R", 2, 5, 6, {"D": 3}) == (2, 3, 3, 3)
    assert expected_shape("lights", 2, 5, 6, {"L": 4}) == (2, 4, 7)
    assert expected_shape("class_name", 4, 8, 10) == (4,)
    assert check_arrays(make_arrays(n=3, h=8, w=10)) == (3, 8, 10)

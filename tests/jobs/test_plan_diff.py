"""spm_data.jobs.plan_diff: the refusal of a shard made from another plan names the key and both values."""

from pathlib import Path

import numpy as np

from spm_data.errors import Option, ShardError, SpmError
from spm_data.jobs.plan_diff import GENERIC, first_difference, flatten, plain, refusal, show, shown


def test_flatten_writes_ranges_as_the_spec_does():
    tree = {"camera": {"azimuth": {"start": 0, "stop": 350, "step": 10}, "distances": [0.6, 0.7]}, "seed": 3}
    assert flatten(tree) == {"camera.azimuth": [0, 350, 10], "camera.distances": [0.6, 0.7], "seed": 3}


def test_plain_and_show_read_as_a_spec_or_an_option():
    assert plain(np.float64(2.0)) == 2 and plain(np.array([1.5, 2.0])) == [1.5, 2]
    assert show("camera.azimuth", [0, 340.0, 20]) == "camera.azimuth = [0, 340, 20]"
    assert show("render.renderer", "pyrender") == 'render.renderer = "pyrender"'
    assert show("--max", 0.6) == "--max 0.6" and show("--flag", True) == "--flag true" and show("k", None) == "k = none"
    assert shown(Option("max"), 0.6) == ("max", " 0.6") and isinstance(shown(Option("max"), 0.6)[0], Option)
    assert shown("--limit", 8) == ("--limit 8",) and shown("seed", 3) == ("seed = 3",)


def test_first_difference_in_order_and_with_missing_keys():
    assert first_difference({"a": 1, "b": 2}, {"a": 1, "b": 3}) == ("b", 2, 3)
    assert first_difference({"a": 1}, {"a": 1, "c": 5}) == ("c", None, 5)
    assert first_difference({"a": 1, "z": 0}, {"a": 1}) == ("z", 0, None)
    assert first_difference({"a": np.int64(1)}, {"a": 1.0}) is None


class Job:
    def __init__(self, found):
        self.found = found

    def plan_difference(self, attrs):
        if isinstance(self.found, Exception):
            raise self.found
        return self.found


def test_refusal_names_the_key_a_phrase_or_falls_back():
    target = Path("out/cup-00000.h5")
    tail = "; write into a new --out folder or delete out"
    assert refusal(Job(("seed", 0, 7)), target, {}) == (f"{target} was made with seed = 0, not seed = 7{tail}",)
    assert refusal(Job("was made from another version of its input"), target, {}) == \
        (f"{target} was made from another version of its input{tail}",)
    for job in (Job(None), Job(KeyError("spec")), Job(SpmError("old shard")), object()):
        assert refusal(job, target, {}) == (f"{target} {GENERIC}{tail}",)


def test_a_refusal_keeps_an_option_key_apart_for_the_command_lines_flag():
    target = Path("out/cup-00000.h5")
    error = ShardError(*refusal(Job((Option("max"), 0.6, 0.9)), target, {}))
    tail = "; write into a new --out folder or delete out"
    assert str(error) == f"{target} was made with max 0.6, not max 0.9{tail}"
    assert error.named({"max": "--max"}) == f"{target} was made with --max 0.6, not --max 0.9{tail}"

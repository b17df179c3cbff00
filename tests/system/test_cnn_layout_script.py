"""benchmarks/cnn_layout.py: times the cnn network in both memory layouts and prints their ratio."""

import re

from tests.helpers import load_script


def test_it_prints_both_layouts_times_and_their_ratio(capsys):
    import torch

    threads = torch.get_num_threads()
    assert load_script("benchmarks/cnn_layout.py", "cnn_layout").main(["--steps", "1", "--rounds", "1",
                                                                        "--threads", str(threads + 1)]) == 0
    out = capsys.readouterr().out
    assert torch.get_num_threads() == threads
    assert out.startswith("torch ") and f"{threads + 1} thread(s)" in out and "1 rounds of 1 steps" in out
    for what in ("training step, batch 64", "embedding 512 crops"):
        line = next(line for line in out.splitlines() if line.startswith(what))
        nchw, last, ratio = map(float, re.findall(r"([\d.]+)(?: ms|x)", line))
        assert nchw > 0 and last > 0 and abs(ratio - nchw / last) < 0.02 * ratio + 0.01


def test_bad_arguments_are_one_line(capsys):
    assert load_script("benchmarks/cnn_layout.py", "cnn_layout").main(["--side", "20"]) == 1
    assert capsys.readouterr().err.startswith("error: ")

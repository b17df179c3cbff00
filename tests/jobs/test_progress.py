"""spm_data.jobs.progress: a bar on a terminal, a line every $SPM_PROGRESS_EVERY seconds elsewhere,
with count, rate and time left; stage and tracked for scripts."""

import io
import re
import time

import pytest

from spm_data.jobs.progress import Progress, stage, tracked


def wait_for(condition, timeout=30.0):
    """Poll ``condition`` until it holds (a state, not a fixed sleep); fail after ``timeout`` s."""
    deadline = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < deadline, "timed out waiting"
        time.sleep(0.005)


class Terminal(io.StringIO):
    def isatty(self):
        return True


LINE = re.compile(r"^render: [\d,]+/5,000 frames, [\d,.]+ frames/s, (\d+ min )?\d+ s left$")


def test_off_a_terminal_a_fed_progress_prints_a_line_with_rate_and_time_left(monkeypatch):
    monkeypatch.setenv("SPM_PROGRESS_EVERY", "0.05")
    out = io.StringIO()
    with Progress("frame", "render", total=5000, stream=out) as progress:
        assert progress.bar is None   # not a terminal: no bar
        progress(1234)
        progress.started = progress.counted - 30   # as if fed over 30 s (at once, the time left would be 0)
        wait_for(lambda: out.getvalue().count("\n") >= 2)
    lines = out.getvalue().splitlines()
    assert all(LINE.match(line) for line in lines), lines
    assert lines[0].startswith("render: 1,234/5,000 frames, ")
    stopped = out.getvalue()
    assert progress._ticker is not None and not progress._ticker.is_alive() and out.getvalue() == stopped


def test_the_line_says_count_rate_and_time_left_and_no_time_left_without_a_total(monkeypatch):
    monkeypatch.setenv("SPM_PROGRESS_EVERY", "3600")
    with Progress("frame", "render", total=5000, stream=io.StringIO()) as progress:
        progress(1234)
        progress.started = time.monotonic() - 30   # as if fed over 30 s
        assert progress.line() == "render: 1,234/5,000 frames, 41.1 frames/s, 1 min 32 s left"
        progress.phase("import coil100", None, "image")
        progress(3)
        progress.started = time.monotonic() - 60
        assert progress.line() == "import coil100: 3 images, 3.0 images/min"
        progress.phase("report", None, None)   # a step that counts nothing
        progress.started = time.monotonic() - 75
        assert progress.line() == "report: 1 min 15 s so far"


def test_the_time_left_counts_down_between_long_items_and_is_not_guessed_once_run_out(monkeypatch):
    """fig5's `fitting: 1/4 splits` once said 48 s left, then 2 min 48 s while nothing ended."""
    monkeypatch.setenv("SPM_PROGRESS_EVERY", "3600")
    with Progress("split", "fitting", total=4, stream=io.StringIO()) as progress:
        assert progress.line() == "fitting: 0/4 splits, 0 splits/s"   # nothing ended: no time left
        progress(1)
        now = time.monotonic()
        progress.started, progress.counted = now - 10, now        # the first split took 10 s
        assert progress.line().endswith(", 30 s left")
        progress.started, progress.counted = now - 25, now - 15   # ... and nothing has ended for 15 s since
        assert progress.line().endswith(", 15 s left")
        progress.started, progress.counted = now - 50, now - 40   # past the guess: none is made
        assert "left" not in progress.line()
        progress(1)   # the next one ends: a new guess from the rate of both
        progress.started = time.monotonic() - 50
        assert progress.line().endswith(", 50 s left")


def test_a_run_shorter_than_the_interval_prints_nothing(monkeypatch):
    monkeypatch.delenv("SPM_PROGRESS_EVERY", raising=False)   # the default: 10 s
    out = io.StringIO()
    with Progress("frame", "render", total=10, stream=out) as progress:
        assert progress.every == 10
        for _ in range(10):
            progress(1)
    assert out.getvalue() == ""


@pytest.mark.parametrize("stream", [io.StringIO, Terminal])
def test_negative_deltas_take_frames_back(stream, monkeypatch):
    monkeypatch.setenv("SPM_PROGRESS_EVERY", "3600")
    with Progress("frame", "render", total=10, stream=stream()) as progress:
        progress(6)
        progress(-4)   # a crashed shard's frames, redone
        assert progress.done == 2 and progress.line().startswith("render: 2/10 frames, ")
        progress(-5)
        assert progress.line().startswith("render: 0/10 frames, 0 frames/s")   # never below 0, no time left
        progress.total = 4   # a new count of the same step
        progress(1)
        assert progress.line().startswith("render: 1/4 frames")


def test_on_a_terminal_it_is_a_bar_and_log_lines_go_to_stdout(capsys):
    out = Terminal()
    with Progress("frame", "render", total=4, stream=out) as progress:
        assert progress._ticker is None
        progress(2)
        progress.write("a log line")
        progress.phase("fitting", 3, "split")
        progress(1)
    assert "render" in out.getvalue() and "1/3" in out.getvalue() and "split" in out.getvalue()
    assert capsys.readouterr().out == "a log line\n"


def test_tracked_counts_the_items():
    assert list(tracked(range(5), "scan", "flip")) == [0, 1, 2, 3, 4]


def test_a_stage_says_its_label_on_stderr_and_counts_nothing_without_a_unit(capsys, monkeypatch):
    monkeypatch.setenv("SPM_PROGRESS_EVERY", "3600")
    with stage("fitting splits") as progress:
        assert progress.label == "fitting splits" and progress.unit is None
    assert capsys.readouterr().err.startswith("fitting splits\n")


def test_without_a_label_the_line_says_progress(monkeypatch):
    monkeypatch.setenv("SPM_PROGRESS_EVERY", "3600")
    with Progress("frame", stream=io.StringIO()) as progress:
        progress(2)
        assert progress.line().startswith("progress: 2 frames, ")

"""benchmarks/fig5.py: the options that made OUT's data are recorded there and a rerun with
other ones stops in one line; its short Fig. 5 table names its columns, each bin's frames and σ over runs."""

import importlib.util
import json
import shlex
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def fig5():
    spec = importlib.util.spec_from_file_location("fig5_script", ROOT / "benchmarks" / "fig5.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def refusal(fig5, argv, capsys) -> str:
    with pytest.raises(SystemExit) as e:
        fig5.main(argv)
    assert e.value.code not in (0, None)
    assert capsys.readouterr().out == ""   # stopped before any stage
    return str(e.value.code)


def test_other_data_options_are_refused_before_anything_is_done(fig5, tmp_path, capsys):
    out = tmp_path / "x"
    assert fig5.claim(out, fig5.data_options(fig5.parse(["--quick", "--out", str(out)])), record=fig5.OPTIONS)
    before = sorted(p.name for p in out.iterdir())
    assert refusal(fig5, ["--out", str(out), "--step", "5"], capsys) == (
        f"error: {out} was made with --step 20, not --step 5; give another --out or the same options")
    assert refusal(fig5, ["--quick", "--out", str(out), "--max", "0.9"], capsys) == (
        f"error: {out} was made with --max 0.6, not --max 0.9; give another --out or the same options")
    assert refusal(fig5, ["--quick", "--out", str(out), "--distractors"], capsys) == (
        f"error: {out} was made with --no-distractors, not --distractors; give another --out or the same options")
    assert refusal(fig5, ["--quick", "--out", str(out), "--classes", "box"], capsys) == (
        f"error: {out} was made with --classes box,cup, not --classes box; give another --out or the same options")
    assert sorted(p.name for p in out.iterdir()) == before   # nothing written, specs least of all
    # Options of the training and report only: the same data.
    same = fig5.parse(["--quick", "--out", str(out), "--runs", "1", "--methods", "pca", "--workers", "1"])
    assert fig5.claim(out, fig5.data_options(same), record=fig5.OPTIONS) is False
    # Data of an older fig5.py, which recorded nothing: refused too.
    old = tmp_path / "old"
    (old / "train").mkdir(parents=True)
    message = refusal(fig5, ["--quick", "--out", str(old)], capsys)
    assert message.startswith(f"error: {old} holds {old / 'train'} from an older fig5.py") and "\n" not in message


def test_quick_sets_defaults_that_options_beside_it_override(fig5):
    args = fig5.parse(["--quick", "--views", "7"])
    assert (args.classes, args.step, args.views, args.max, args.distractors, args.runs) == (
        ["box", "cup"], 20, 7, 0.6, False, 3)
    plain = fig5.parse([])
    assert plain.runs == 3 and plain.max == 0.95 and plain.distractors and plain.step == 10


def _rows(frames, rate, std):
    return [{"low": i / 10, "high": (i + 1) / 10, "frames": n, "success_sum5": rate, "success_sum3": rate,
             "success_tol5": rate, "std": {"success_sum5": std}} for i, n in enumerate(frames)]


def test_fig5_table_names_its_columns_shows_each_bins_frames_marks_the_few_and_carries_sigma(fig5):
    frames = [48, 25, 20, 31, 19, 22, 0, 0, 0, 0]
    summary = {"runs": 3, "fig5": {"seen": {"rectangles": {"spm": _rows(frames, 84.0, 2.4),
                                                           "chance": _rows(frames, 0.0, 0.0)}}}}
    lines = fig5.fig5_table(summary).splitlines()
    assert lines[0] == ("Fig. 5 (seen instances, rectangles): sum < 5° success % per occlusion bin, mean ± σ over "
                        "3 runs; * under 20 frames, too few to read")
    assert [line.split() for line in lines[1:]] == [
        ["occluded", "0%-10%", "10%-20%", "20%-30%", "30%-40%", "40%-50%", "50%-60%"],   # empty bins left out
        ["frames", "n=48", "n=25", "n=20", "n=31", "n=19*", "n=22"],
        ["spm", *["84±2"] * 6], ["chance", *["0±0"] * 6]]
    # Every column is right-aligned under its header: the cells end where the bin's name ends.
    assert {len(line) for line in lines[1:]} == {len(lines[1])}
    one = fig5.fig5_table({"runs": 1, "fig5": {"seen": {"rectangles": {"spm": _rows([30] * 6, 50.0, None)}}}})
    assert "1 run" in one and "*" not in one and one.splitlines()[-1].split() == ["spm", *["50"] * 6]


def test_a_small_run_records_its_command_and_resumes(fig5, tmp_path, capsys):
    out = tmp_path / "f5"
    argv = ["--out", str(out), "--classes", "cup", "--step", "60", "--size", "64", "--views", "4", "--copies", "1",
            "--no-distractors", "--runs", "2", "--methods", "pca,chance", "--workers", "1"]
    assert fig5.main(argv) == 0
    said = capsys.readouterr().out
    for stage in ("render the training grid", "render 4 test views", "occlude", "train and test pca, chance, 2 runs"):
        assert f"fig5: {stage}" in said, stage
    assert json.loads((out / fig5.OPTIONS).read_text())["--step"] == 60
    report = json.loads((out / "report" / "results.json").read_text())
    assert report["context"]["command"] == shlex.join(["python", "benchmarks/fig5.py", *argv])
    assert report["summary"]["runs"] == 2
    specs = {p: p.read_bytes() for p in (out / "specs").rglob("*.toml")}
    # The same data options, another --runs: resumed, nothing made again.
    assert fig5.main(argv[:-6] + ["--runs", "1", "--methods", "pca,chance", "--workers", "1"]) == 0
    said = capsys.readouterr().out
    assert "resumed (made with these options)" in said and said.count("rendered 0 shards") == 2
    assert "occluded 0 shards" in said
    assert {p: p.read_bytes() for p in (out / "specs").rglob("*.toml")} == specs
